"""The Dockerfile's install, repeated in a fresh virtual environment (no Docker engine needed).

The COPY sources and the ``pip install`` argument are read from the Dockerfile itself, so the
test follows the image. It checks that the ``[serve]`` install leaves torch out, that
``fisheye-infer serve --help`` works, and that the installed server answers the image's
HEALTHCHECK. Bounded by timeouts; deselect with ``-m "not install"``.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCKERFILE = ROOT / "Dockerfile"

pytestmark = pytest.mark.install


def dockerfile_steps() -> tuple[list[str], str, str]:
    """(COPY sources, pip install argument, HEALTHCHECK python code) as the Dockerfile states them."""
    text = DOCKERFILE.read_text().replace("\\\n", " ")
    sources = [src for line in re.findall(r"^COPY (.+)$", text, re.M) for src in shlex.split(line)[:-1]]
    (spec,) = re.findall(r"RUN pip install (\S+)", text)
    (check,) = re.findall(r'HEALTHCHECK .*CMD python -c "(.+)"', text)
    return sources, shlex.split(spec)[0], check


def test_dockerfile_is_torch_free_and_non_root() -> None:
    text = DOCKERFILE.read_text()
    assert re.search(r"^FROM python:3\.\d+-slim", text, re.M)
    assert re.search(r"^USER (?!root)\w+", text, re.M) and "/healthz" in text
    assert (
        "FISHEYE_MODEL_PATH=/models/model.onnx" in text and "[serve]" in text and "torch" not in dockerfile_steps()[1]
    )


def _run(args: list[str], timeout: float, **kwargs) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, **kwargs)


def test_serve_extra_installs_without_torch_and_serves(tmp_path: Path, small_export) -> None:
    sources, spec, healthcheck = dockerfile_steps()
    src = tmp_path / "src"
    src.mkdir()
    for name in sources:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(path, src / name)
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], 120).check_returncode()
    bin_ = venv / "bin"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "PYTHONPATH"))}
    installed = _run([str(bin_ / "pip"), "install", "-q", spec.replace(".", str(src), 1)], 600, env=env)
    assert installed.returncode == 0, installed.stderr[-3000:]

    no_torch = _run(
        [str(bin_ / "python"), "-c", "import importlib.util as u; print(u.find_spec('torch'))"], 60, env=env
    )
    assert no_torch.stdout.strip() == "None", no_torch.stdout
    help_ = _run([str(bin_ / "fisheye-infer"), "serve", "--help"], 60, env=env)
    assert help_.returncode == 0 and "--port" in help_.stdout, help_.stderr

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server_env = {
        **env,
        "FISHEYE_MODEL_PATH": str(small_export.onnx),
        "FISHEYE_PORT": str(port),
        "FISHEYE_THREADS": "1",
    }
    server = subprocess.Popen(
        [str(bin_ / "fisheye-infer"), "serve"],
        env=server_env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            probe = _run([str(bin_ / "python"), "-c", healthcheck], 10, env=server_env)
            if probe.returncode == 0:
                break
            assert server.poll() is None and time.monotonic() < deadline, (
                server.stderr.read() if server.poll() is not None else "no answer"
            )
            time.sleep(0.2)
    finally:
        server.terminate()
        server.wait(30)
    assert server.returncode == 0
