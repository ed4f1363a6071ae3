"""What every model configuration dataclass shares: JSON saving, strict loading and versions.

A config is saved as ``config.json`` beside its weights. Loading is strict: an unknown key
(a typo, or a config of another model) or another ``model_type`` is an :class:`InputError`
naming the file, never silently ignored.

A config class with a ``config_version`` field (every model type of the core, through
:class:`cnfmp.core.configuration_common.MotionConfig`) writes its version into the file.
Loading a file of an older version upgrades it step by step (:meth:`JsonConfig.upgrade`,
which a class overrides when it changes a field's meaning or name, raising the field's
default) or refuses it with a message that says to retrain; a file of a newer version is
refused with a message that says to update cnfmp. A file without ``config_version`` is of
the version its reader says (``unversioned``): model directories written before versions
existed are version 1 (:func:`cnfmp.core.models.read_config`), a config file of training
settings is of the current version.
"""

from __future__ import annotations

import dataclasses
import json

from cnfmp.errors import InputError

#: The key of a config's format version (an integer >= 1).
VERSION_FIELD = "config_version"


class JsonConfig:
    """Mixin for ``@dataclass`` configs with a ``model_type`` field whose default names the
    model and, optionally, a ``config_version`` field whose default is the version this
    cnfmp writes."""

    def check(self, source: str = "config") -> None:
        """InputError for values no model can be built with (subclasses add their rules)."""

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2) + "\n"

    @classmethod
    def current_version(cls) -> int | None:
        """The config version this cnfmp writes and reads (the ``config_version`` field's
        default), or None for a class without versions."""
        fields = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
        return fields[VERSION_FIELD].default if VERSION_FIELD in fields else None

    @classmethod
    def upgrade(cls, values: dict, version: int, source: str) -> dict:
        """The fields `values` of a config of `version` (older than the current one) as a
        config of `version` + 1 would hold them (without ``config_version``). Here: no
        version can be upgraded, an InputError; a class that changes its fields overrides
        this for the versions it can still read."""
        raise InputError(f"{source}: config_version {version} is a config format this cnfmp cannot read "
                         f"(it reads version {cls.current_version()}); retrain the model with `cnfmp train`")

    @classmethod
    def from_dict(cls, values: dict, source: str = "config", unversioned: int | None = None):
        """A config from a dict; unknown keys are an InputError naming them.

        For a class with versions: `values` without ``config_version`` are of version
        `unversioned` (default: the current one); a version above the current one, or one
        that is not a whole number >= 1, is refused; an older one is upgraded step by step
        (:meth:`upgrade`) to the current one."""
        fields = {f.name: f for f in dataclasses.fields(cls)}
        # Another model's config has other fields too: name the real mistake first.
        expected = fields["model_type"].default
        if values.get("model_type", expected) != expected:
            raise InputError(f"{source}: model_type is {values['model_type']!r}, expected {expected!r}")
        values = cls._upgraded(values, source, unversioned)
        unknown = sorted(set(values) - set(fields))
        if unknown:
            raise InputError(f"{source}: unknown field(s) {', '.join(unknown)}; known: {', '.join(sorted(fields))}")
        config = cls(**values)
        config.check(source)
        return config

    @classmethod
    def _upgraded(cls, values: dict, source: str, unversioned: int | None) -> dict:
        """`values` brought to the current version (see :meth:`from_dict`)."""
        current = cls.current_version()
        if current is None:
            return values
        version = values.get(VERSION_FIELD, current if unversioned is None else unversioned)
        if isinstance(version, bool) or not isinstance(version, int) or version < 1:
            raise InputError(f"{source}: {VERSION_FIELD} must be a whole number >= 1, got {version!r}")
        if version > current:
            raise InputError(f"{source}: {VERSION_FIELD} {version} was written by a newer cnfmp (this one reads "
                             f"versions up to {current}); update cnfmp to load it")
        values = {k: v for k, v in values.items() if k != VERSION_FIELD}
        while version < current:
            values = cls.upgrade(values, version, source)
            version += 1
        return {**values, VERSION_FIELD: current}

    @classmethod
    def from_file(cls, path, unversioned: int | None = None):
        """A config from a JSON file of config fields; InputError naming the file when it is
        unreadable, not a JSON object, or has unknown or invalid fields (or a version this
        cnfmp cannot read; `unversioned` as in :meth:`from_dict`)."""
        return cls.from_dict(read_json_object(path), source=str(path), unversioned=unversioned)


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


__all__ = ["VERSION_FIELD", "JsonConfig", "read_json_object"]
