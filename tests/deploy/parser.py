"""The real `docker-compose config` parser (Debian's docker-compose 1.29, which needs no Docker engine for it).

It is a system package that bootstrap.sh installs; a machine without it FAILS these tests rather than skipping
them, since the generated compose file is otherwise never checked by anything Docker would run. PyYAML comes
with it (docker-compose's own interpreter), so the tests also read our YAML back with the reader Docker uses.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

MISSING = "the docker-compose parser is missing (Debian: apt-get install docker-compose; bootstrap.sh installs it)"


def docker_compose() -> str:
    found = shutil.which("docker-compose")
    if found is None:
        pytest.fail(MISSING)
    return found


def compose_config(compose_file: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    """`docker-compose -f FILE config ...` run in the file's directory (as a person would)."""
    return subprocess.run(
        [docker_compose(), "-f", str(compose_file), *("config", *extra)],
        cwd=compose_file.parent,
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )


def _compose_python() -> str:
    """docker-compose is a Python script; its interpreter has PyYAML."""
    first = Path(docker_compose()).read_text(errors="replace").splitlines()[0]
    if not first.startswith("#!"):
        pytest.fail(f"{docker_compose()} is not the Python docker-compose 1.x (no #! line)")
    return first[2:].strip().split()[0]


def read_yaml(text: str) -> Any:
    """YAML text as docker-compose's PyYAML reads it (safe_load), through JSON."""
    code = "import json, sys, yaml; print(json.dumps(yaml.safe_load(sys.stdin.read())))"
    done = subprocess.run(
        [_compose_python(), "-c", code], check=False, input=text, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)
