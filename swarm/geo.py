"""World frame <-> geodetic and ENU <-> NED conversions (local tangent plane, fine within a few km).

The simulator reports a vehicle's global position as the mission origin plus its world position; an agent
inverts that to place its drone in the shared world frame. A real deployment does the same with the
geodetic origin of the site.
"""

from __future__ import annotations

import math

from swarm.config import GeoOrigin, Vec3

EARTH_RADIUS_M = 6378137.0


def world_to_geo(origin: GeoOrigin, p: Vec3) -> tuple[float, float, float]:
    """World (x east, y north, z up) -> (lat_deg, lon_deg, alt_amsl_m)."""
    lat = origin.lat_deg + math.degrees(p[1] / EARTH_RADIUS_M)
    lon = origin.lon_deg + math.degrees(p[0] / (EARTH_RADIUS_M * math.cos(math.radians(origin.lat_deg))))
    return lat, lon, origin.alt_amsl_m + p[2]


def geo_to_world(origin: GeoOrigin, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Vec3:
    """(lat_deg, lon_deg, alt_amsl_m) -> world (x east, y north, z up)."""
    y = math.radians(lat_deg - origin.lat_deg) * EARTH_RADIUS_M
    x = math.radians(lon_deg - origin.lon_deg) * EARTH_RADIUS_M * math.cos(math.radians(origin.lat_deg))
    return x, y, alt_amsl_m - origin.alt_amsl_m


def enu_to_ned(v: Vec3) -> Vec3:
    return v[1], v[0], -v[2]


def ned_to_enu(v: Vec3) -> Vec3:
    return v[1], v[0], -v[2]


def yaw_enu_to_ned_deg(yaw_enu_deg: float) -> float:
    """ENU yaw (0 = east, counter-clockwise) -> NED yaw (0 = north, clockwise)."""
    return (90.0 - yaw_enu_deg + 180.0) % 360.0 - 180.0


yaw_ned_to_enu_deg = yaw_enu_to_ned_deg  # the mapping is its own inverse
