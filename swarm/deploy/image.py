"""`swarm deploy image`: the swarm image, built from Debian's packages and PyPI only, with Podman or Docker.

Where no container registry is reachable there is no `python:3.11-slim-bookworm` to start from, so:

1. the base, `localhost/swarm-base:bookworm`, once per machine: `debootstrap --variant=minbase bookworm` into a
   temporary directory with python3, python3-venv and the system packages of deploy/Dockerfile (the libraries
   Open3D links against, iproute2, nftables), imported with `<engine> import` (about 400 MB, a minute);
2. the image, `deploy/Containerfile` from the repository root: a venv with the package installed by pip,
   pip's cache a build cache mount (a rebuild downloads nothing again).

The image carries the label `org.swarm.sources`, a hash of what goes into it (pyproject.toml, README.md,
every file under swarm/, deploy/Containerfile): when the image of that name already holds these sources the
build is skipped (`--force` rebuilds), so the container test and a developer's loop build once per change.

A host whose way to PyPI goes through a TLS-inspecting proxy gives pip that proxy's CA bundle: `--ca-bundle`,
else $PIP_CERT, else $SSL_CERT_FILE. It reaches the build as the secret `pip-ca`, never a layer of the image.

With Podman on hosts such as Debian 12's (cgroups in hybrid mode, no right to raise RLIMIT_NOFILE), set
CONTAINERS_CONF to deploy/containers.conf, as docs/deploy.md says.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from swarm.config import ConfigError
from swarm.errors import SwarmError

BASE_IMAGE = "localhost/swarm-base:bookworm"
CONTAINERFILE = "deploy/Containerfile"
SOURCES_LABEL = "org.swarm.sources"
SUITE = "bookworm"
BASE_PACKAGES = (
    "python3",
    "python3-venv",
    "ca-certificates",
    "libusb-1.0-0",  # import open3d fails without it (DESIGN section 10)
    "libgl1",
    "libegl1",
    "libx11-6",
    "libgomp1",
    "iproute2",  # swarm deploy netem: ip, tc
    "nftables",  # swarm deploy netem without sch_netem
)
_SOURCE_FILES = ("pyproject.toml", "README.md", CONTAINERFILE)


def engine_of(choice: str) -> str:
    """The container engine to use: `choice`, or with "auto" podman if installed, else docker."""
    candidates = ("podman", "docker") if choice == "auto" else (choice,)
    for name in candidates:
        if shutil.which(name):
            return name
    raise SwarmError(f"no container engine: {' or '.join(candidates)} is not installed (docs/deploy.md)")


def sources_hash(repo: Path) -> str:
    """sha256 over the image's inputs: names and contents, in a fixed order (caches are never hashed)."""
    files = [repo / name for name in _SOURCE_FILES]
    files += sorted(p for p in (repo / "swarm").rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    digest = hashlib.sha256()
    for path in files:
        digest.update(str(path.relative_to(repo)).encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def _run(argv: list[str], doing: str, stdin: int | None = None) -> str:
    try:
        done = subprocess.run(argv, stdin=stdin, capture_output=True, text=True, check=False)
    except OSError as exc:
        raise SwarmError(f"cannot {doing}: {argv[0]}: {exc.strerror}") from None
    if done.returncode != 0:
        lines = [line for line in (done.stderr or done.stdout).splitlines() if line.strip()]
        raise SwarmError(f"cannot {doing}: {lines[-1] if lines else f'{argv[0]} exited {done.returncode}'}")
    return done.stdout


def image_label(engine: str, image: str, label: str) -> str | None:
    """The image's label value, or None when there is no such image (or label)."""
    done = subprocess.run(
        [engine, "image", "inspect", "--format", f'{{{{index .Config.Labels "{label}"}}}}', image],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        return None
    value = done.stdout.strip()
    return value if value and value != "<no value>" else None


def image_exists(engine: str, image: str) -> bool:
    return image_id(engine, image) is not None


def image_id(engine: str, image: str) -> str | None:
    done = subprocess.run(
        [engine, "image", "inspect", "--format", "{{.Id}}", image], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        return None
    return done.stdout.strip() or None


def build_base(engine: str, image: str = BASE_IMAGE) -> None:
    """debootstrap a Debian 12 minbase with BASE_PACKAGES and import it as `image` (root, debootstrap needed)."""
    if shutil.which("debootstrap") is None:
        raise SwarmError("cannot build the base image: debootstrap is not installed (apt-get install debootstrap)")
    if os.geteuid() != 0:
        raise SwarmError("cannot build the base image: debootstrap needs root")
    with tempfile.TemporaryDirectory(prefix="swarm-rootfs-", dir="/var/tmp") as tmp:
        rootfs = Path(tmp) / "rootfs"
        _run(
            ["debootstrap", "--variant=minbase", f"--include={','.join(BASE_PACKAGES)}", SUITE, str(rootfs)],
            f"debootstrap {SUITE}",
        )
        for cache in ("var/cache/apt/archives", "var/lib/apt/lists"):
            for path in (rootfs / cache).glob("*"):
                if path.is_file():
                    path.unlink()
        tar = subprocess.Popen(["tar", "-C", str(rootfs), "-c", "."], stdout=subprocess.PIPE)
        try:
            assert tar.stdout is not None
            _run(
                [engine, "import", "--change", 'CMD ["/bin/bash"]', "-", image], f"import {image}", tar.stdout.fileno()
            )
        finally:
            if tar.stdout is not None:
                tar.stdout.close()
            tar.wait()


def ca_bundle_of(given: Path | None) -> Path | None:
    if given is not None:
        if not given.is_file():
            raise ConfigError(f"--ca-bundle {given} is not a file")
        return given
    for var in ("PIP_CERT", "SSL_CERT_FILE"):
        value = os.environ.get(var)
        if value and Path(value).is_file():
            return Path(value)
    return None


def build_image(
    repo: Path, tag: str, engine: str, force: bool = False, ca_bundle: Path | None = None
) -> tuple[bool, str]:
    """Build `tag` from `repo` unless it already holds these sources; returns (built, sources hash)."""
    if not (repo / CONTAINERFILE).is_file() or not (repo / "swarm").is_dir():
        raise ConfigError(f"--repo {repo} is not the swarm repository (no {CONTAINERFILE})")
    sources = sources_hash(repo)
    if not force and image_label(engine, tag, SOURCES_LABEL) == sources:
        return False, sources
    if not image_exists(engine, BASE_IMAGE):
        build_base(engine)
    previous = image_id(engine, tag)
    argv = [engine, "build", "--network", "host", "-f", CONTAINERFILE, "-t", tag]
    argv += ["--build-arg", f"BASE={BASE_IMAGE}", "--label", f"{SOURCES_LABEL}={sources}"]
    if ca_bundle is not None:
        argv += ["--secret", f"id=pip-ca,src={ca_bundle.resolve()}"]
    done = subprocess.run([*argv, "."], cwd=repo, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        lines = [line for line in (done.stderr + done.stdout).splitlines() if line.strip()]
        raise SwarmError(f"cannot build {tag}: {lines[-1] if lines else f'{engine} build failed'}")
    if previous is not None and previous != image_id(engine, tag):
        # the image this tag named before: 1.5 GB that nothing names any more (kept if a container uses it)
        subprocess.run([engine, "rmi", previous], capture_output=True, check=False)
    return True, sources


def deploy_image_command(repo: Path, tag: str, engine: str, force: bool, ca_bundle: Path | None) -> int:
    chosen = engine_of(engine)
    started = time.monotonic()
    built, sources = build_image(repo, tag, chosen, force, ca_bundle_of(ca_bundle))
    if built:
        print(f"built {tag} with {chosen} in {time.monotonic() - started:.0f} s (sources {sources[:12]})")
    else:
        print(f"{tag} is up to date (sources {sources[:12]}); --force rebuilds")
    return 0
