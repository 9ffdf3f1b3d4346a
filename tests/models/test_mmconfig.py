"""The config reader bounds every value it builds: by ``*`` and ``+``, by calls and literals, per value
and over the whole file, so a short hostile file cannot build gigabytes."""

from __future__ import annotations

import os
import re
import time

import pytest

from fisheye_infer.errors import ConfigError
from fisheye_infer.models.mmconfig import evaluate_config_source, read_mmdet3d_config

DOUBLED = 's = "x" * 1000000\n' + "s = s + s\n" * 6  # 64 MB if each line were built


@pytest.mark.parametrize(
    "source, words",
    [
        (DOUBLED, "building a value of 2,000,000 items"),  # line 2 already refused
        ("a = [0] * 600000\nb = a + a", "1,200,000 items"),
        ("t = (0,) * 600000\nu = t + t", "1,200,000 items"),
        ('s = "x" * 2000000', "2,000,000 items"),
        ('s = "%099999999d" % 1', "'%' formatting of a string"),
        ('a = "x" * 900000\n' + "".join(f"b{i} = a + 'y'\n" for i in range(40)), "more than 20,000,000 items in all"),
        ('a = list("x" * 900000)\nb = list(a + a)', "1,800,000 items"),
        ('n = int("9" * 4000)', "an integer of more than 4096 bits"),
        ("x = 1" + " + 1" * 100_000, "nested too deeply"),
    ],
)
def test_oversized_values_are_refused_before_they_are_built(source: str, words: str) -> None:
    started = time.perf_counter()
    with pytest.raises(ConfigError) as err:
        evaluate_config_source(source, "evil.py")
    assert words in str(err.value) and "evil.py" in str(err.value)
    assert time.perf_counter() - started < 10  # refused, not built and swapped


def test_ordinary_arithmetic_on_sequences_still_works() -> None:
    cfg = evaluate_config_source(
        'a = [1, 2] + [3]\nb = (1,) + (2,)\nc = "ab" + "cd"\nd = dict(x=1, **{"y": 2})\ne = "-" * 3\nf = 7 % 3\n'
    )
    assert cfg == {"a": [1, 2, 3], "b": (1, 2), "c": "abcd", "d": {"x": 1, "y": 2}, "e": "---", "f": 1}


@pytest.mark.parametrize(
    "files, words",
    [
        ({"c.py": b"\xff\xfe\x00\x01" * 100}, "not a Python config file (not UTF-8: byte 0)"),
        ({"c.py": b"a = 1\x00\n"}, "c.py: not valid Python (source code string cannot contain null bytes)"),
        ({"c.py": b"a = '" + b"x" * (4 * 1024 * 1024) + b"'\n"}, "more than 4,194,304 bytes"),
        ({"c.py": b"_base_ = ['c.py']\n"}, "_base_ refers back to a file it is based on"),
        ({"c.py": b"_base_ = 'b.py'\n", "b.py": b"_base_ = ['c.py']\nx = 1\n"}, "refers back to a file it is based on"),
        ({"c.py": b"_base_ = [5]\n"}, "_base_: expected file names, got int"),
        ({"c.py": b"_base_ = 'missing.py'\n"}, "cannot read configuration"),
    ],
)
def test_hostile_config_files_are_refused_by_name(tmp_path, files: dict[str, bytes], words: str) -> None:
    """A binary file was a UnicodeDecodeError, a file that is its own base a RecursionError."""
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    with pytest.raises(ConfigError, match=re.escape(words)):
        read_mmdet3d_config(tmp_path / "c.py", merge_bases=True)


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_a_device_is_read_only_to_the_size_limit() -> None:
    with pytest.raises(ConfigError, match="/dev/zero: more than"):
        read_mmdet3d_config("/dev/zero")
