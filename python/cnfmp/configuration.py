"""What every model configuration dataclass shares: JSON saving and strict loading.

A config is saved as ``config.json`` beside its weights. Loading is strict: an unknown key
(a typo, or a config of another model) or another ``model_type`` is an :class:`InputError`
naming the file, never silently ignored.
"""

from __future__ import annotations

import dataclasses
import json

from cnfmp.errors import InputError


class JsonConfig:
    """Mixin for ``@dataclass`` configs with a ``model_type`` field whose default names the model."""

    def check(self, source: str = "config") -> None:
        """InputError for values no model can be built with (subclasses add their rules)."""

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2) + "\n"

    @classmethod
    def from_dict(cls, values: dict, source: str = "config"):
        """A config from a dict; unknown keys are an InputError naming them."""
        fields = {f.name: f for f in dataclasses.fields(cls)}
        # Another model's config has other fields too: name the real mistake first.
        expected = fields["model_type"].default
        if values.get("model_type", expected) != expected:
            raise InputError(f"{source}: model_type is {values['model_type']!r}, expected {expected!r}")
        unknown = sorted(set(values) - set(fields))
        if unknown:
            raise InputError(f"{source}: unknown field(s) {', '.join(unknown)}; known: {', '.join(sorted(fields))}")
        config = cls(**values)
        config.check(source)
        return config

    @classmethod
    def from_file(cls, path):
        """A config from a JSON file of config fields; InputError naming the file when it is
        unreadable, not a JSON object, or has unknown or invalid fields."""
        return cls.from_dict(read_json_object(path), source=str(path))


def read_json_object(path) -> dict:
    """The JSON object in the config file `path`; InputError naming the file when it is
    unreadable or holds something else."""
    try:
        with open(path, encoding="utf-8") as f:
            values = json.load(f)
    except OSError as err:
        raise InputError(f"cannot read config {path}: {err.strerror}") from err
    except ValueError as err:
        raise InputError(f"config {path} is not valid JSON: {err}") from err
    if not isinstance(values, dict):
        raise InputError(f"config {path}: expected a JSON object of config fields")
    return values


__all__ = ["JsonConfig", "read_json_object"]
