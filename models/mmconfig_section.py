"""Reading the namespace of an evaluated official config: `Section` and `as_tuple`.

`Section` reads one dict of the namespace
[`read_mmdet3d_config`][fisheye_infer.models.mmconfig.read_mmdet3d_config] returns, every value
converted to tuples and numbers on the way out, every error naming the file and the key's path.
All model configurations read their official files through it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from fisheye_infer.errors import ConfigError

__all__ = ["Section", "as_tuple"]


def as_tuple(value: Any) -> Any:
    """Lists and tuples, nested, as tuples; anything else unchanged."""
    if isinstance(value, (list, tuple)):
        return tuple(as_tuple(v) for v in value)
    return value


class Section:
    """One dict of an official config namespace, read with the file and the key's path named in every error.

    model = Section(cfg.get("model"), "model", "fisheye_bevdet.py")
    head = model.sub("bbox_head")                  # missing: "fisheye_bevdet.py: 'model.bbox_head' is missing"
    head.get("num_proposals", 200)                 # lists come back as tuples
    head.numbers("post_center_range", 6)           # six numbers, or a ConfigError naming the key
    """

    def __init__(self, data: Any, path: str, source: str) -> None:
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: expected a dict at '{path}', got {type(data).__name__}")
        self.data: Mapping[str, Any] = data
        self.path, self.source = path, source

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def where(self, key: str) -> str:
        return f"{self.path}.{key}"

    def sub(self, key: str, *, required: bool = True) -> Section:
        """The dict at ``key``; absent (or None) and not ``required``: an empty one."""
        value = self.data.get(key)
        if value is None:
            if required:
                raise ConfigError(f"{self.source}: '{self.where(key)}' is missing")
            value = {}
        return Section(value, self.where(key), self.source)

    def get(self, key: str, default: Any = None) -> Any:
        return as_tuple(self.data.get(key, default))

    def numbers(self, key: str, count: int, kind: type = float) -> tuple[Any, ...]:
        """``count`` numbers at ``key`` (which must be present), converted with ``kind``."""
        value = self.data[key]
        try:
            values = tuple(kind(v) for v in value)
        except (TypeError, ValueError):
            raise ConfigError(f"{self.source}: '{self.where(key)}' must be {count} numbers, got {value!r}") from None
        if len(values) != count:
            raise ConfigError(f"{self.source}: '{self.where(key)}' must be {count} numbers, got {len(values)}")
        return values

    def type_is(self, *allowed: str, required: bool = False) -> None:
        """Refuse a ``type`` other than ``allowed`` (and a missing one when ``required``)."""
        kind = self.data.get("type")
        if (kind is not None or required) and kind not in allowed:
            raise ConfigError(
                f"{self.source}: '{self.where('type')}' is {kind!r}, expected {' or '.join(map(repr, allowed))}"
            )

    def refuse(self, key: str, expected: Any, value: Any, why: str = "") -> ConfigError:
        return ConfigError(f"{self.source}: {self.where(key)}={value!r} is not supported (expected {expected!r}{why})")
