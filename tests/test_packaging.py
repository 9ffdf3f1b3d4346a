"""The package as a user installs it: one namespace, a torch-free core, a working CLI."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import fisheye_infer
from fisheye_infer._moved import MOVED, new_name
from fisheye_infer.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out), str(ROOT)],
        check=True,
        capture_output=True,
    )
    (path,) = out.glob("fisheye_infer-*.whl")
    return path


def test_wheel_installs_one_namespace(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names}
    assert {t for t in top if not t.endswith(".dist-info")} == {"fisheye_infer"}
    for sub in (
        "models",
        "export",
        "service",
        "cameras",
        "geometry",
        "runtime",
        "deploy",
        "deploy/triton",
        "tools",
        "scenes",
        "eval",
    ):
        assert f"fisheye_infer/{sub}/__init__.py" in names
    assert "fisheye_infer/data/rig-fisheye3dod/calib_results.txt" in names
    assert "fisheye_infer/models/manifests/fisheye_bevdet_keys.json" in names
    for folder in ("fisheye_bevdet_compact", "fisheye_petr_compact"):
        shipped = f"fisheye_infer/models/pretrained/{folder}"
        files = ("model.pth", "config.py", "rig.json", "MODEL_CARD.md", "heldout_frame/labels.json")
        assert {f"{shipped}/{n}" for n in files} <= set(names)


BLOCK_HEAVY = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in {'torch', 'fastapi', 'uvicorn', 'starlette', 'onnx', 'matplotlib', 'ray', 'tritonclient', 'grpc',
                                  'rosbags', 'mcap', 'mcap_protobuf', 'foxglove_schemas_protobuf'}:
            raise ImportError(f'{name} is not installed')
sys.meta_path.insert(0, Block())
"""


def test_core_imports_without_torch_or_web_stack() -> None:
    code = BLOCK_HEAVY + (
        "import fisheye_infer, fisheye_infer.geometry, fisheye_infer.cameras.rig, fisheye_infer.cameras.ocam_fit, fisheye_infer.tools.viz, fisheye_infer.cli\n"
        "import fisheye_infer.deploy.ray_batch, fisheye_infer.deploy.triton, fisheye_infer.deploy.triton.repository\n"
        "r = fisheye_infer.default_rig(); print(len(r))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "4"


def test_import_loads_neither_torch_nor_fastapi() -> None:
    code = "import sys, fisheye_infer; print(sorted(m for m in ('torch', 'fastapi', 'uvicorn', 'onnx', 'ray', 'tritonclient') if m in sys.modules))"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_public_names() -> None:
    for name in fisheye_infer.__all__:
        assert hasattr(fisheye_infer, name), name
    assert {"OCamModel", "KannalaBrandt", "Rig", "default_rig", "FisheyeInferError", "__version__"} <= set(
        fisheye_infer.__all__
    )


def _subcommands() -> list[str]:
    parser = build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return sorted(action.choices)


def test_version() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "fisheye_infer", "--version"], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == f"fisheye-infer {fisheye_infer.__version__}"


@pytest.mark.parametrize("command", _subcommands())
def test_every_subcommand_has_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        build_parser().parse_args([command, "--help"])
    assert exit_info.value.code == 0
    assert "usage: fisheye-infer " + command in capsys.readouterr().out


def test_missing_ray_or_triton_extra_names_the_install_line(tmp_path: Path) -> None:
    code = BLOCK_HEAVY + (
        "from fisheye_infer.deploy.triton import TritonDetector\n"
        "try:\n    TritonDetector('127.0.0.1:8000', 'm')\nexcept ImportError as exc:\n    print(exc)\n"
        "from fisheye_infer.deploy.ray_batch import detect_frames\n"
        "try:\n    detect_frames('m.onnx', [])\nexcept ImportError as exc:\n    print(exc)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert (
        "pip install 'fisheye-infer[triton]'" in result.stdout and "pip install 'fisheye-infer[ray]'" in result.stdout
    )


def test_missing_ros_extra_names_the_install_line(tmp_path: Path) -> None:
    code = BLOCK_HEAVY + (
        "from fisheye_infer.cli import main\n"
        f"print(main(['replay', 'm.onnx', 'b.mcap', '--camera', 'a=/a', '--out', {str(tmp_path / 'o.mcap')!r}]))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0 and result.stdout.strip() == "1", result.stderr
    assert "pip install 'fisheye-infer[ros]'" in result.stderr


MOVED_CHECK = """
import importlib, json, sys, warnings
import fisheye_infer
from fisheye_infer._moved import MOVED, new_name
report = {}
for old in sorted(MOVED):
    new = importlib.import_module(new_name(old))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
    report[old] = [module is new, [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning)]]
print(json.dumps(report))
"""


def test_moved_modules_import_from_their_old_paths_with_a_warning() -> None:
    """Every old path is the moved module itself, and importing it warns once, naming the new path."""
    result = subprocess.run([sys.executable, "-c", MOVED_CHECK], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.splitlines()[-1])
    assert sorted(report) == sorted(MOVED)
    for old, (same, warned) in report.items():
        expected = f"{old} is now {new_name(old)}; the old path will be removed in the next release"
        assert same and warned == [expected], old


def test_moved_submodule_follows_its_package() -> None:
    assert new_name("fisheye_infer.triton.client") == "fisheye_infer.deploy.triton.client"
    assert new_name("fisheye_infer.rigs") is None
    assert new_name("fisheye_infer.cameras.rig") is None
