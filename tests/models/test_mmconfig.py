"""The config reader bounds every value it builds: by ``*`` and ``+``, by calls and literals, per value
and over the whole file, so a short hostile file cannot build gigabytes."""

from __future__ import annotations

import time

import pytest

from fisheye_infer.errors import ConfigError
from fisheye_infer.models.mmconfig import evaluate_config_source

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
