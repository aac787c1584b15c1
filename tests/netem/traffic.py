"""Test traffic inside a swarm network namespace (run as `python traffic.py MODE ...` via SwarmNetwork.exec_argv).

    udp-recv PORT              print "ready", count datagrams until a line (or EOF) on stdin, print {"received": n}
    udp-send HOST PORT COUNT   send COUNT numbered 200-byte datagrams, paced so no queue on the way overflows
    tcp-recv PORT              print "ready", accept one connection, print {"bytes": n, "seconds": first byte to EOF}
    tcp-send HOST PORT SECONDS send as fast as the link allows for SECONDS, then close

Receivers exit on their own after 60 s so that a broken test cannot leave them behind.
"""

from __future__ import annotations

import argparse
import json
import select
import socket
import sys
import time

_SAFETY_S = 60.0
_SO_RCVBUFFORCE = 33  # Linux; not exported by the socket module


def udp_recv(port: int) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, _SO_RCVBUFFORCE, 8 << 20)  # root may exceed rmem_max: no drops here
    sock.bind(("0.0.0.0", port))
    print("ready", flush=True)
    received = 0
    deadline = time.monotonic() + _SAFETY_S
    while time.monotonic() < deadline:
        readable, _, _ = select.select([sock, sys.stdin], [], [], 1.0)
        if sock in readable:
            sock.recv(2048)
            received += 1
        elif sys.stdin in readable:
            break
    sock.setblocking(False)
    while True:  # whatever arrived together with the stop request
        try:
            sock.recv(2048)
        except BlockingIOError:
            break
        received += 1
    print(json.dumps({"received": received}), flush=True)


def udp_send(host: str, port: int, count: int) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for seq in range(count):
        sock.sendto(seq.to_bytes(4, "big") + bytes(196), (host, port))
        if seq % 20 == 19:
            time.sleep(0.001)  # veth delivers into a per-CPU backlog of 1000 frames: do not burst past it


def tcp_recv(port: int) -> None:
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("0.0.0.0", port))
    server.listen(1)
    server.settimeout(_SAFETY_S)
    print("ready", flush=True)
    conn, _ = server.accept()
    conn.settimeout(_SAFETY_S)
    total, first = 0, 0.0
    while chunk := conn.recv(65536):
        if not total:
            first = time.monotonic()
        total += len(chunk)
    print(json.dumps({"bytes": total, "seconds": time.monotonic() - first}), flush=True)


def tcp_send(host: str, port: int, seconds: float) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 32 << 10)  # little left to drain after the deadline
    sock.connect((host, port))
    block = bytes(16384)
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        sock.sendall(block)
    sock.close()


def main() -> None:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="mode", required=True)
    sub.add_parser("udp-recv").add_argument("port", type=int)
    p = sub.add_parser("udp-send")
    p.add_argument("host"), p.add_argument("port", type=int), p.add_argument("count", type=int)
    sub.add_parser("tcp-recv").add_argument("port", type=int)
    p = sub.add_parser("tcp-send")
    p.add_argument("host"), p.add_argument("port", type=int), p.add_argument("seconds", type=float)
    args = parser.parse_args()
    if args.mode == "udp-recv":
        udp_recv(args.port)
    elif args.mode == "udp-send":
        udp_send(args.host, args.port, args.count)
    elif args.mode == "tcp-recv":
        tcp_recv(args.port)
    else:
        tcp_send(args.host, args.port, args.seconds)


if __name__ == "__main__":
    main()
