"""What the CPU offers that changes how ONNX Runtime runs an int8 file: its name, generation and instruction-set flags.

ONNX Runtime multiplies u8 activations by s8 weights with VNNI's ``vpdpbusd`` where the CPU has it
(AVX-512 VNNI or AVX-VNNI), adding in int32. Without it but with AVX2 (AVX2-only CPUs, AVX-512
before Cascade Lake) it uses ``vpmaddubsw``, which adds each pair of products in int16 and
saturates: int8 files with 8-bit weights can then give other boxes than on a VNNI CPU. (Older x86
CPUs get SSE2 kernels that widen to int16 before multiplying: exact, and slow.) ``export`` writes
7-bit weights, which never saturate (``fisheye_infer.precision.WEIGHT_BITS``);
``int8_saturation_warning`` names the older files at risk on this CPU.
"""

from __future__ import annotations

import contextlib
import platform
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from fisheye_infer.runtime.artifact import ArtifactMeta

__all__ = ["CpuInfo", "cpu_info", "int8_saturation_warning"]

VNNI_FLAGS = ("avx512_vnni", "avx_vnni")


@dataclass(frozen=True)
class CpuInfo:
    """The CPU's model name and flags as Linux lists them (``/proc/cpuinfo``); empty flags where unknown.

    ``family`` and ``model`` are x86's generation numbers. Cloud machines often name the CPU only by
    its line ("AMD EPYC"), and the generations behind one name differ about 2x in float throughput
    per core (Zen 4 runs AVX-512 at half width, Zen 5 at full width), which moves every speed-up
    measured against fp32. ``label`` puts them beside the name.

    Attributes:
        name (str): The model name (``model name`` in ``/proc/cpuinfo``).
        flags (frozenset[str]): The instruction-set flags (``avx2``, ``avx512f``, ``avx512_vnni``...).
        family (str): x86's ``cpu family`` number, empty where unknown.
        model (str): x86's ``model`` number, empty where unknown.
    """

    name: str
    flags: frozenset[str]
    family: str = ""
    model: str = ""

    @property
    def label(self) -> str:
        """The name, with the family and model numbers where Linux lists them: what figures should quote."""
        return f"{self.name} (family {self.family}, model {self.model})" if self.family and self.model else self.name

    @property
    def avx2(self) -> bool:
        """Whether the CPU has AVX2."""
        return "avx2" in self.flags

    @property
    def avx512(self) -> bool:
        """Whether the CPU has AVX-512 (``avx512f``)."""
        return "avx512f" in self.flags

    @property
    def vnni(self) -> bool:
        """Whether the CPU has VNNI (AVX-512 or AVX): int8 dot products without saturation."""
        return any(flag in self.flags for flag in VNNI_FLAGS)


def cpu_info(cpuinfo: Path = Path("/proc/cpuinfo")) -> CpuInfo:
    """What this machine's CPU is and offers, from the first processor's entry of ``cpuinfo``.

    Args:
        cpuinfo (Path): The file to read (Linux's ``/proc/cpuinfo``).

    Returns:
        CpuInfo: The name, flags, family and model; where the file cannot be read (not Linux), the platform's
            name and no flags.
    """
    fields: dict[str, str] = {}
    with contextlib.suppress(OSError):
        for line in cpuinfo.read_text(errors="replace").split("\n\n", 1)[0].splitlines():
            key, colon, value = line.partition(":")
            if colon:
                fields.setdefault(key.strip(), value.strip())
    # Arm lists "Features", not "flags" (and 64-bit Arm no "model name")
    return CpuInfo(
        fields.get("model name") or platform.processor() or "unknown",
        frozenset(fields.get("flags", "").split()),
        fields.get("cpu family", ""),
        fields.get("model", ""),
    )


def int8_saturation_warning(meta: ArtifactMeta, providers: Iterable[str], cpu: CpuInfo) -> str | None:
    """Why this int8 file may give other boxes on this CPU than where it was verified, or None.

    At risk: an int8 file with 8-bit weights (written before weights were limited to 7 bits, which
    record no ``weight_bits``) run by ONNX Runtime's CPU provider on an x86 CPU with AVX2 and without
    VNNI. Where the flags are unknown (not Linux) nothing is said.
    """
    q = meta.quantization
    if q is None or q.mode != "int8-qdq" or (q.weight_bits or 8) <= 7:
        return None
    if "CPUExecutionProvider" not in list(providers)[:1] or not cpu.avx2 or cpu.vnni:
        return None
    return (
        f"model {meta.model_id}: int8 with {q.weight_bits or 8}-bit weights on a CPU without VNNI ({cpu.name}): "
        "ONNX Runtime adds u8 x s8 products in saturating int16 pairs here, so boxes can differ from the verified "
        "ones; export the int8 file again (fisheye-infer export --int8 writes 7-bit weights, which never saturate)"
    )
