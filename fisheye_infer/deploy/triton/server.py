"""A real ``tritonserver`` on this machine: the one the ``nvidia-pytriton`` wheel bundles, with its Python backend.

    with TritonServer("model_repository") as server:          # 127.0.0.1, free ports, ready when entered
        detector = TritonDetector(server.http_url, "fisheye_bevdet")
        detector = TritonDetector(server.grpc_url, "fisheye_bevdet", protocol="grpc")

The wheel (Linux x86-64, glibc 2.35+) is installed without its Python dependencies
(``pip install --no-deps nvidia-pytriton==0.7.0``; they pin numpy below 2): only its files are used. The server
runs from them as they lie: the binary, its bundled libraries on ``LD_LIBRARY_PATH``, and a backend folder made
for the current interpreter (the wheel's Python backend with the stub built for this Python version). The stub
embeds this interpreter's ``libpython`` and finds this environment first on ``PATH``, so the repository's
``model.py`` imports fisheye_infer and ONNX Runtime from the environment that started the server. It serves the
Python-backend repository form (``TritonOptions(backend="python")``); it has no ONNX Runtime backend.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import sysconfig
import tempfile
import time
import urllib.error
import urllib.request
from importlib.util import find_spec
from pathlib import Path
from types import TracebackType

from fisheye_infer.errors import ConfigError, InferenceError

__all__ = ["INSTALL", "TritonServer", "bundled_server", "free_port", "server_unavailable"]

#: How to install the bundled server.
INSTALL = "pip install --no-deps nvidia-pytriton==0.7.0 (Linux x86-64, glibc 2.35 or newer)"


def _stub(root: Path) -> Path:
    """The wheel's Python backend stub built for this Python version."""
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    return root / "python_backend_stubs" / version / "triton_python_backend_stub"


def bundled_server() -> Path:
    """The ``pytriton/tritonserver`` folder of the installed ``nvidia-pytriton`` wheel.

    Returns:
        Path: The folder holding ``bin/tritonserver``, ``backends/python`` and the Python backend stubs.

    Raises:
        ConfigError: The wheel is not installed, or lacks the server or the stub for this Python version.
    """
    spec = find_spec("pytriton")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError(f"no Triton server here: {INSTALL}")
    root = Path(next(iter(spec.submodule_search_locations))) / "tritonserver"
    for needed in (root / "bin" / "tritonserver", root / "backends" / "python", _stub(root)):
        if not needed.exists():
            raise ConfigError(f"the nvidia-pytriton wheel lacks {needed} (Python {sys.version.split()[0]})")
    return root


_LIBPYTHON = f"libpython{sys.version_info.major}.{sys.version_info.minor}.so.1.0"


def _libpython() -> Path | None:
    """The folder holding this interpreter's shared ``libpython`` for the stub, or None where there is none."""
    libdir = sysconfig.get_config_var("LIBDIR")
    if libdir and sysconfig.get_config_var("Py_ENABLE_SHARED") and (Path(libdir) / _LIBPYTHON).exists():
        return Path(libdir)
    return None


def server_unavailable() -> str | None:
    """Why [`TritonServer`][fisheye_infer.deploy.triton.server.TritonServer] cannot start here, or None when it can.

    Checks the platform (Linux x86-64), the ``nvidia-pytriton`` wheel with its server and the Python backend stub
    for this Python version, and a shared ``libpython`` for the stub to embed. Nothing is started.

    Returns:
        The reason (naming the install line where the wheel is missing), or None when the server can start.
    """
    if sys.platform != "linux" or os.uname().machine != "x86_64":
        return f"the bundled Triton server runs on Linux x86-64 only (this is {sys.platform} {os.uname().machine})"
    try:
        bundled_server()
    except ConfigError as exc:
        return str(exc)
    if _libpython() is None:
        return f"the Python backend's stub embeds {_LIBPYTHON}, which this Python does not provide (a shared build)"
    return None


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (the OS's choice).

    Returns:
        int: The port.
    """
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class TritonServer:
    """The ``tritonserver`` bundled with the ``nvidia-pytriton`` wheel, serving a model repository on 127.0.0.1.

    The server has Triton's Python backend only, so it serves the repository form written with
    ``TritonOptions(backend="python")``; its ``model.py`` runs in this environment's interpreter. Used as a context
    manager, it is started (and ready) on entry and stopped on exit; it is always stopped by its PID.
    [`server_unavailable`][fisheye_infer.deploy.triton.server.server_unavailable] says beforehand whether it can
    start here (install: ``pip install --no-deps nvidia-pytriton==0.7.0``, Linux x86-64, glibc 2.35 or newer).

    Args:
        repository (str | Path): The model repository folder.
        http_port (int | None): The HTTP port; None for a free one.
        grpc_port (int | None): The gRPC port; None for a free one.
        exit_on_error (bool): Exit when a model fails to load (Triton's default); False keeps the server up, ready
            without that model, and the failure readable from the repository index.
        startup_timeout_s (float): How long ``start`` waits for readiness, in seconds.
        exit_timeout_s (int): How long the server waits for in-flight requests once told to stop, in seconds.

    Raises:
        ConfigError: ``repository`` is not a folder.

    Examples:
        ```python
        from fisheye_infer.deploy.triton.client import TritonDetector
        from fisheye_infer.deploy.triton.repository import TritonOptions, write_repository
        from fisheye_infer.deploy.triton.server import TritonServer

        write_repository("model.onnx", "model_repository", TritonOptions(name="fisheye_bevdet", backend="python"))
        with TritonServer("model_repository") as server:
            detector = TritonDetector(server.grpc_url, "fisheye_bevdet", protocol="grpc")
        ```
    """

    def __init__(
        self,
        repository: str | Path,
        *,
        http_port: int | None = None,
        grpc_port: int | None = None,
        exit_on_error: bool = True,
        startup_timeout_s: float = 120.0,
        exit_timeout_s: int = 5,
    ) -> None:
        self.repository = Path(repository).resolve()
        if not self.repository.is_dir():
            raise ConfigError(f"model repository {self.repository}: not a folder")
        self.http_port = http_port or free_port()
        self.grpc_port = grpc_port or free_port()
        self.exit_on_error = exit_on_error
        self.startup_timeout_s = startup_timeout_s
        self.exit_timeout_s = exit_timeout_s
        self.process: subprocess.Popen[bytes] | None = None
        self._workspace: Path | None = None

    @property
    def http_url(self) -> str:
        """The HTTP endpoint, ``127.0.0.1:<port>``."""
        return f"127.0.0.1:{self.http_port}"

    @property
    def grpc_url(self) -> str:
        """The gRPC endpoint, ``127.0.0.1:<port>``."""
        return f"127.0.0.1:{self.grpc_port}"

    @property
    def log_path(self) -> Path:
        """The server's log (stdout and stderr); a ``ConfigError`` before ``start``."""
        if self._workspace is None:
            raise ConfigError("the Triton server has not been started")
        return self._workspace / "tritonserver.log"

    def log_tail(self, chars: int = 4000) -> str:
        """The end of the server's log.

        Args:
            chars (int): How many characters from the end.

        Returns:
            str: The log's last ``chars`` characters ('' before the server started).
        """
        if self._workspace is None or not self.log_path.exists():
            return ""
        return self.log_path.read_text(errors="replace")[-chars:]

    def _environment(self, root: Path) -> dict[str, str]:
        env = dict(os.environ)
        libs = [root.parent.parent / "nvidia_pytriton.libs"]
        libpython = _libpython()
        if libpython is not None:
            libs.insert(0, libpython)  # the stub embeds this interpreter's libpython
        env["LD_LIBRARY_PATH"] = os.pathsep.join([*map(str, libs), *filter(None, [env.get("LD_LIBRARY_PATH")])])
        env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
        return env

    def start(self) -> TritonServer:
        """Start the server and wait until it reports ready.

        Returns:
            TritonServer: This server, ready.

        Raises:
            ConfigError: No bundled server here (see ``server_unavailable``).
            InferenceError: The server exited or was not ready within ``startup_timeout_s`` (its log's end quoted).
        """
        root = bundled_server()
        self._workspace = Path(tempfile.mkdtemp(prefix="fisheye-infer-triton-"))
        backends = self._workspace / "backends"
        shutil.copytree(root / "backends", backends)
        shutil.copy2(_stub(root), backends / "python" / "triton_python_backend_stub")
        command = [
            str(root / "bin" / "tritonserver"),
            f"--model-repository={self.repository}",
            f"--backend-directory={backends}",
            f"--cache-directory={root / 'caches'}",
            "--http-address=127.0.0.1",
            f"--http-port={self.http_port}",
            "--grpc-address=127.0.0.1",
            f"--grpc-port={self.grpc_port}",
            "--allow-metrics=false",
            f"--exit-on-error={str(self.exit_on_error).lower()}",
            f"--strict-readiness={str(self.exit_on_error).lower()}",
            f"--exit-timeout-secs={self.exit_timeout_s}",
        ]
        with open(self.log_path, "wb") as log:
            self.process = subprocess.Popen(
                command, stdout=log, stderr=subprocess.STDOUT, env=self._environment(root), start_new_session=True
            )
        deadline = time.monotonic() + self.startup_timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                code, tail = self.process.returncode, self.log_tail()
                self.stop()
                raise InferenceError(f"tritonserver exited with code {code} while starting:\n{tail}")
            if self._ready():
                return self
            time.sleep(0.2)
        tail = self.log_tail()
        self.stop()
        raise InferenceError(f"tritonserver not ready within {self.startup_timeout_s:g} s:\n{tail}")

    def _ready(self) -> bool:
        try:
            with urllib.request.urlopen(f"http://{self.http_url}/v2/health/ready", timeout=1.0) as answer:
                return bool(answer.status == 200)
        except (urllib.error.URLError, OSError):
            return False

    def stop(self, timeout_s: float = 30.0) -> None:
        """Stop the server by its PID (SIGTERM, then SIGKILL after ``timeout_s``) and remove its workspace and log.

        The Python backend's stub processes, in the server's process group, are killed with it if they outlive it.

        Args:
            timeout_s (float): How long to wait for a clean exit, in seconds.
        """
        if self.process is not None:
            if self.process.poll() is None:
                self.process.send_signal(signal.SIGTERM)
                try:
                    self.process.wait(timeout_s)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait()
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.process.pid, signal.SIGKILL)
        if self._workspace is not None:
            shutil.rmtree(self._workspace, ignore_errors=True)

    def __enter__(self) -> TritonServer:
        return self.start()

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.stop()
