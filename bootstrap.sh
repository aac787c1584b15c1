#!/usr/bin/env bash
# Sets up everything Swarm needs on Debian 12 with Python 3.11 (as root, or with sudo), then runs a job:
#
#   ./bootstrap.sh run  [swarm run flags]   fly a simulated swarm in a built-in world, report in runs/
#   ./bootstrap.sh test                     run the test suite: the lint gates (ruff), the type check (mypy),
#                                           the unit and fuzz tiers, then every other tier (each on 2 workers);
#                                           each stops the run on its failure
#   ./bootstrap.sh test [pytest flags]      pytest with these flags (e.g. -m unit -n 2, or one file)
#   ./bootstrap.sh env                      only set up; prints the environment's path
#
# Installs the system libraries Open3D links against, the tools the network experiments use, the
# docker-compose parser the deployment tests validate with (no Docker engine: --no-install-recommends) and
# rootful Podman with what it needs on Debian 12 to run the compose swarm in containers (runc, catatonit for
# `init: true`, iptables and the CNI plugins for its bridges, debootstrap for the base image; podman-compose
# comes with the test extras, since Debian's 1.0.3 places no static addresses), creates a
# virtual environment in .venv (or uses the one that is active) and installs the package with its test
# extras there. Each step is skipped when already done, so running it again costs a second.
set -euo pipefail
cd "$(dirname "$0")"

SYSTEM_PACKAGES=(libusb-1.0-0 libgl1 libegl1 libx11-6 libgomp1 iproute2 nftables docker-compose chromium
  podman runc catatonit iptables containernetworking-plugins debootstrap)

say() { printf 'bootstrap: %s\n' "$*" >&2; }

install_system_packages() {
  local missing=()
  for pkg in "${SYSTEM_PACKAGES[@]}"; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
  done
  python3 -c 'import ensurepip, venv' >/dev/null 2>&1 || missing+=(python3-venv)
  [ ${#missing[@]} -eq 0 ] && return
  local sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  say "installing system packages: ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

python_env() {
  if [ -n "${VIRTUAL_ENV:-}" ]; then
    echo "$VIRTUAL_ENV"
    return
  fi
  if [ ! -x .venv/bin/python ]; then
    say "creating virtual environment .venv"
    python3 -m venv .venv
  fi
  echo "$PWD/.venv"
}

install_package() {
  local env="$1" stamp="$1/.swarm-setup-stamp" want
  want="$(sha256sum pyproject.toml | cut -d' ' -f1) $PWD"
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    return
  fi
  say "installing swarm and its dependencies into $env"
  "$env/bin/python" -m pip install -q --upgrade pip >/dev/null
  "$env/bin/python" -m pip install -q -e '.[test,ros2]'
  echo "$want" >"$stamp"
}

job="${1:-}"
[ $# -gt 0 ] && shift
case "$job" in
  run | test | env) ;;
  *) echo "usage: ./bootstrap.sh run|test|env [args...]" >&2; exit 2 ;;
esac

install_system_packages
env_dir="$(python_env)"
install_package "$env_dir"

case "$job" in
  run) exec "$env_dir/bin/swarm" run "$@" ;;
  test)
    if [ $# -gt 0 ]; then exec "$env_dir/bin/python" -m pytest "$@"; fi
    say "gates: ruff check, ruff format --check"
    "$env_dir/bin/ruff" check --quiet .
    "$env_dir/bin/ruff" format --check --quiet .
    say "gates: mypy (pyproject.toml: the package, strict on the runtime packages)"
    "$env_dir/bin/mypy"
    say "unit and fuzz tiers (pytest -m 'unit or fuzz' -n 2)"
    "$env_dir/bin/python" -m pytest -m "unit or fuzz" -n 2 -q
    say "every other tier on 2 workers: two tests at a time, network tests one at a time, 'alone' tests" \
      "alone (tests/conftest.py); the 25 slowest tests are listed at the end"
    exec "$env_dir/bin/python" -m pytest -m "not unit and not fuzz" -n 2 --durations=25 ;;
  env) echo "$env_dir" ;;
esac
