"""CPU flags as Linux lists them: what decides whether ONNX Runtime's int8 kernels add in saturating int16 pairs."""

from __future__ import annotations

from pathlib import Path

import pytest

from fisheye_infer.tools.cpu import cpu_info

X86 = """processor\t: 0
vendor_id\t: GenuineIntel
cpu family\t: 6
model\t\t: 158
model name\t: Intel(R) Core(TM) i7-7700 CPU @ 3.60GHz
flags\t\t: fpu vme sse sse2 ssse3 fma sse4_1 sse4_2 avx avx2 {extra}
vmx flags\t: vnmi preemption_timer avx512_vnni_lookalike
bugs\t\t: spectre_v1

processor\t: 1
model name\t: Intel(R) Core(TM) i7-7700 CPU @ 3.60GHz
flags\t\t: fpu vme sse sse2 ssse3 fma sse4_1 sse4_2 avx avx2 {extra}
"""

ARM = """processor\t: 0
BogoMIPS\t: 243.75
Features\t: fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics asimddp
CPU implementer\t: 0x41
"""


@pytest.mark.parametrize(
    ("extra", "avx512", "vnni"),
    [
        ("", False, False),  # AVX2 only (Skylake client, Zen 2/3)
        ("avx512f avx512bw avx512vl", True, False),  # AVX-512 before VNNI (Skylake-SP)
        ("avx512f avx512bw avx512_vnni", True, True),  # Cascade Lake and later, Zen 4
        ("avx_vnni", False, True),  # AVX-VNNI on an AVX2 core (Alder Lake)
    ],
)
def test_cpu_info_reads_the_flags_line(tmp_path: Path, extra: str, avx512: bool, vnni: bool) -> None:
    path = tmp_path / "cpuinfo"
    path.write_text(X86.format(extra=extra))
    cpu = cpu_info(path)
    assert cpu.name == "Intel(R) Core(TM) i7-7700 CPU @ 3.60GHz"
    assert cpu.label == "Intel(R) Core(TM) i7-7700 CPU @ 3.60GHz (family 6, model 158)"  # 'model name' is not 'model'
    assert cpu.avx2
    assert (cpu.avx512, cpu.vnni) == (avx512, vnni)
    assert "vnmi" not in cpu.flags  # the 'vmx flags' line is another list


def test_cpu_info_without_x86_flags(tmp_path: Path) -> None:
    path = tmp_path / "cpuinfo"
    path.write_text(ARM)
    cpu = cpu_info(path)
    assert not cpu.vnni and cpu.flags == frozenset()
    assert cpu.label == cpu.name  # no family and model numbers to add
    missing = cpu_info(tmp_path / "absent")
    assert missing.flags == frozenset() and missing.name
