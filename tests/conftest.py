"""Shared fixtures: the real calibration files and the official geometry tables."""

from __future__ import annotations

import os
import pickle
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.rig import Rig, default_rig

DATA = Path(__file__).parent / "data"
SAMPLE_FRAME = Path(__file__).parents[1] / "fisheye_infer" / "data" / "sample_frame"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    return DATA


@pytest.fixture(scope="session")
def official() -> dict[str, np.ndarray]:
    """Tables the official constructors compute for the shipped rig (see tests/data)."""
    with np.load(DATA / "official_geometry.npz") as npz:
        return {k: npz[k] for k in npz.files}


@pytest.fixture(scope="session")
def rig() -> Rig:
    return default_rig()


@pytest.fixture(scope="session")
def ocam800(rig: Rig) -> OCamModel:
    return rig.shared_model()


@pytest.fixture(scope="session")
def ocam1600() -> OCamModel:
    return OCamModel.from_file(DATA / "ocam_sample_1600.txt", fov=360)


# -- the fast lane: tests of full-size models, whole exports and Ray are `slow` ------------------

#: Fixtures that build, export or run a full-size model (the official configurations, the shipped
#: model), or start Ray: a test that uses one is marked ``slow`` and left out of ``make test-fast``.
SLOW_FIXTURES = frozenset(
    {
        "bevdet_export",
        "petr_export",
        "exported",
        "petr_fp16",
        "shipped_export",
        "shipped_exports",
        "full_ckpt",
        "full_petr",
        "full_checkpoint",
        "full_model",
        "full_bevdet",
        "kit_bevdet",
        "kit_export",
        "pinhole_model",
        "ray_local",
    }
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if SLOW_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)
    if os.environ.get("PYTEST_XDIST_WORKER"):
        late = {_file(item) for item in items if SHARED_EXPORTS & set(getattr(item, "fixturenames", ()))}
        items.sort(key=lambda item: _rank(_file(item), late))


# -- several workers (`make test`: pytest -n 2 --dist loadfile --no-loadscope-reorder) ------------

#: The files that take longest, handed out first (each file is one worker's unit of work) so that
#: no worker is left alone with one of them at the end. The first builds the session's full-size
#: exports (``SHARED_EXPORTS``); the other files that use them come last, when they are built, and
#: the rest in between, in collection order.
LONGEST_FILES = ("tests/export/test_export.py", "tests/models/test_pinhole.py")
SHARED_EXPORTS = frozenset({"bevdet_export", "petr_export"})


def _file(item: pytest.Item) -> str:
    return item.nodeid.split("::")[0]


def _rank(file: str, late: set[str]) -> int:
    if file in LONGEST_FILES:
        return LONGEST_FILES.index(file)
    return len(LONGEST_FILES) + (file in late)


def pytest_configure(config: pytest.Config) -> None:
    """Under several workers, PyTorch (imported later, here and in the commands the tests start) takes
    one thread in each: two processes of two OpenMP threads on two cores wait on each other's
    descheduled threads at every parallel region."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        os.environ.setdefault("OMP_NUM_THREADS", "1")


# -- exported models, once per session -------------------------------------------------------


@dataclass(frozen=True)
class Exported:
    """A checkpoint and its verified ONNX export."""

    arch: str
    ckpt: Path
    onnx: Path
    result: object  # fisheye_infer.export.exporter.ExportResult


def _shared(
    arch: str, name: str, tmp_path_factory: pytest.TempPathFactory, make: Callable[[Path], tuple[Path, Any]]
) -> Exported:
    """``make(folder)`` (-> checkpoint, ExportResult) run once per run under ``name``: under several workers the
    first to ask exports into the run's shared temporary folder and the others wait for it and read its result."""
    from filelock import FileLock

    if os.environ.get("PYTEST_XDIST_WORKER"):
        folder = tmp_path_factory.getbasetemp().parent / f"shared-{name}"  # the workers' common parent
    else:
        folder = tmp_path_factory.mktemp(name)
    done = folder / "result.pkl"
    with FileLock(f"{folder}.lock"):
        if not done.is_file():
            folder.mkdir(exist_ok=True)
            ckpt, result = make(folder)
            done.write_bytes(pickle.dumps((ckpt, result)))  # an ExportResult: its classes import by their module's name
    ckpt, result = pickle.loads(done.read_bytes())
    return Exported(arch, ckpt, result.path, result)


def _export(arch: str, tmp_path_factory: pytest.TempPathFactory) -> Exported:
    """The kit's checkpoint of ``arch`` exported once per run."""
    pytest.importorskip("torch")
    from checkpoint_kit import kit_checkpoint

    from fisheye_infer.export.exporter import export

    def make(folder: Path) -> tuple[Path, Any]:
        ckpt = kit_checkpoint(arch, folder / f"{arch}.pth")
        return ckpt, export(
            ckpt, folder / f"{arch}.onnx", frames=1, verify_images=SAMPLE_FRAME, progress=lambda _: None
        )

    return _shared(arch, arch, tmp_path_factory, make)


def shipped_export_of(name: str, tmp_path_factory: pytest.TempPathFactory) -> Exported:
    """The shipped model ``name`` exported once per run with the export's defaults (its check included): what the
    shipped-model tests and the docs' runnable snippets share."""
    pytest.importorskip("torch")
    from fisheye_infer.export.exporter import export
    from fisheye_infer.models.pretrained import pretrained

    shipped = pretrained(name)

    def make(folder: Path) -> tuple[Path, Any]:
        out = folder / f"{name}.onnx"
        return shipped.checkpoint, export(
            shipped.checkpoint, out, config=shipped.config, rig=shipped.rig, progress=lambda _: None
        )

    return _shared(name, f"shipped-{name}", tmp_path_factory, make)


def small_export_of(arch: str, tmp_path_factory: pytest.TempPathFactory) -> Exported:
    """The reduced configuration of ``arch`` (``small_configs``) with seeded weights, exported once per run
    for its reduced rig (self-check on one frame at one thread): what the tests of a whole export path share."""
    pytest.importorskip("torch")
    from small_configs import small_configs

    from fisheye_infer.export.exporter import export
    from fisheye_infer.models import make_checkpoint

    config, rig = small_configs()[arch]

    def make(folder: Path) -> tuple[Path, Any]:
        ckpt = folder / f"{arch}.pth"
        make_checkpoint(arch, seed=2, path=ckpt, config=config, rig=rig)
        quiet = {"frames": 1, "threads": (1,), "progress": lambda _: None}
        return ckpt, export(ckpt, folder / f"{arch}.onnx", config=config, rig=rig, **quiet)

    return _shared(arch, f"small-{arch}", tmp_path_factory, make)


@pytest.fixture(scope="session")
def shipped_exports(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Exported]:
    """``shipped_exports(name)``: the run's export of the shipped model ``name`` (``shipped_export_of``)."""
    return lambda name: shipped_export_of(name, tmp_path_factory)


@pytest.fixture(scope="session")
def small_exports(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Exported]:
    """``small_exports(arch)``: the run's export of the reduced ``arch`` (``small_export_of``)."""
    return lambda arch: small_export_of(arch, tmp_path_factory)


@pytest.fixture(scope="session")
def bevdet_export(tmp_path_factory: pytest.TempPathFactory) -> Exported:
    """The kit's FisheyeBEVDet exported for the default rig: self-check on a rendered frame and the bundled
    sample frame (``--verify-images``), at 1 and 2 threads."""
    return _export("fisheye-bevdet", tmp_path_factory)


@pytest.fixture(scope="session")
def petr_export(tmp_path_factory: pytest.TempPathFactory) -> Exported:
    """The kit's FisheyePETR exported for the default rig: self-check on a rendered frame and the bundled
    sample frame (``--verify-images``), at 1 and 2 threads."""
    return _export("fisheye-petr", tmp_path_factory)


@pytest.fixture(scope="session", params=["fisheye-bevdet", "fisheye-petr"])
def exported(request: pytest.FixtureRequest) -> Exported:
    return request.getfixturevalue("bevdet_export" if request.param == "fisheye-bevdet" else "petr_export")


@pytest.fixture(scope="session")
def moved_rig(rig: Rig) -> Rig:
    """The shipped rig with every camera moved (``small_configs.move_rig``)."""
    from small_configs import move_rig

    return move_rig(rig)


@pytest.fixture(scope="session")
def small_bevdet_config():
    """The reduced FisheyeBEVDet of ``small_configs`` (four 160x160 cameras)."""
    pytest.importorskip("torch")
    from small_configs import small_bevdet_config

    return small_bevdet_config()


@pytest.fixture(scope="session")
def small_export(tmp_path_factory: pytest.TempPathFactory, small_bevdet_config) -> Exported:
    """A reduced FisheyeBEVDet (four 160x160 cameras) exported for the shipped rig resized by 0.2:
    the whole graph in seconds, for tests of what surrounds the model (service, CLI)."""
    from fisheye_infer.export.exporter import export
    from fisheye_infer.models import make_checkpoint
    from fisheye_infer.scenes.render import resized_rig

    folder = tmp_path_factory.mktemp("small_export")
    small_rig = resized_rig(default_rig(), 0.2)
    ckpt = folder / "small.pth"
    make_checkpoint("fisheye-bevdet", seed=3, path=ckpt, config=small_bevdet_config, rig=small_rig)
    result = export(ckpt, folder / "small.onnx", config=small_bevdet_config, rig=small_rig, progress=lambda _: None)
    return Exported("fisheye-bevdet", ckpt, result.path, result)


@pytest.fixture(scope="session")
def ray_local():
    """A local Ray for this session only: 2 CPUs, no dashboard, on 127.0.0.1; shut down at the end."""
    ray = pytest.importorskip("ray", reason="needs the [ray] extra")
    ray.init(
        address="local",
        num_cpus=2,
        include_dashboard=False,
        _node_ip_address="127.0.0.1",
        configure_logging=False,
        log_to_driver=False,
    )
    try:
        yield ray
    finally:
        ray.shutdown()
