"""One registry per kind of part (estimator, controller, terrain, gait, sensor, contact model).

A part is named by a spec: a registered name, or `MODULE:ATTRIBUTE` for any importable module (a
file in the current directory, on PYTHONPATH or installed). Names come from the entry point group
of the kind (`hexapod_testbed.estimators`, ...): this package registers its built-ins there in
`pyproject.toml`, and another installed package registers its parts the same way. Listing names
imports nothing; a part is imported when it is resolved.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache, cached_property
from pathlib import Path
from typing import Any

from testbed.model.errors import PluginError, UserError

GROUP_PREFIX = "hexapod_testbed."


@dataclass(frozen=True)
class PluginSource:
    """Where a resolved part came from: what a recording stores to find it again."""
    spec: str
    target: str                 # MODULE:ATTRIBUTE
    module_file: str | None
    module_sha256: str | None
    distribution: str | None    # the installed package that provides the module, if any
    version: str | None

    def to_dict(self) -> dict[str, str | None]:
        return dict(self.__dict__)


class Registry:
    """The parts of one kind. `check(obj)` tells whether a resolved object is a part of this kind
    (for classes: a subclass of the kind's base class)."""

    def __init__(self, kind: str, group: str, check: Callable[[Any], bool], expected: str):
        self.kind = kind
        self.group = GROUP_PREFIX + group
        self.accepts = check
        self.expected = expected
        self._loaded: dict[str, Any] = {}

    @classmethod
    def of_subclasses(cls, kind: str, group: str, base: type) -> "Registry":
        return cls(kind, group, lambda obj: isinstance(obj, type) and issubclass(obj, base),
                   f"a subclass of {base.__module__.split('.')[0]}.{base.__qualname__}")

    @cached_property
    def _entry_points(self) -> dict[str, importlib.metadata.EntryPoint]:
        return {point.name: point for point in importlib.metadata.entry_points(group=self.group)}

    def names(self) -> tuple[str, ...]:
        return tuple(sorted(self._entry_points))

    def is_known(self, spec: str) -> bool:
        return spec in self._entry_points

    def check_spec(self, spec: str) -> None:
        """A registered name or a well-formed MODULE:ATTRIBUTE (not imported yet): else PluginError."""
        if not isinstance(spec, str) or not spec or any(ch in spec for ch in "\r\n\t"):
            raise PluginError(f"{self.kind} spec must be a name or MODULE:CLASS, got {spec!r}")
        if self.is_known(spec):
            return
        if ":" not in spec:
            raise PluginError(f"unknown {self.kind} '{spec}' (choose from {', '.join(self.names())}, "
                              f"or give MODULE:CLASS)")
        module, _, attribute = spec.partition(":")
        if not all(part.isidentifier() for part in module.split(".")) or not attribute.isidentifier():
            raise PluginError(f"{self.kind} spec '{spec}' is not MODULE:CLASS")

    def target(self, spec: str) -> str:
        self.check_spec(spec)
        return self._entry_points[spec].value if self.is_known(spec) else spec

    def resolve(self, spec: str) -> Any:
        """The part named by `spec`, imported; PluginError (one line) when it cannot be."""
        if spec not in self._loaded:
            target = self.target(spec)
            module_name, _, attribute = target.partition(":")
            module = import_plugin_module(module_name, self.kind, spec)
            obj = module
            for name in attribute.split("."):
                obj = getattr(obj, name, None)
                if obj is None:
                    raise PluginError(f"{self.kind} '{spec}': module '{module_name}' has no '{attribute}'")
            if not self.accepts(obj):
                raise PluginError(f"{self.kind} '{spec}' is not {self.expected}")
            self._loaded[spec] = obj
        return self._loaded[spec]

    def build(self, spec: str, *config: Any) -> Any:
        """A new part: `from_config(*config)` when the class has it, else the class called with no
        arguments; any failure is a PluginError naming the spec."""
        cls = self.resolve(spec)
        factory = getattr(cls, "from_config", None)
        try:
            return factory(*config) if factory is not None else cls()
        except UserError:
            raise
        except Exception as error:
            raise PluginError(f"{self.kind} '{spec}' could not be built: {type(error).__name__}: {error}") from None

    def source(self, spec: str) -> PluginSource:
        """What identifies the resolved part: its target, its module file's hash, its distribution."""
        target = self.target(spec)
        module = sys.modules.get(target.partition(":")[0])
        path = getattr(module, "__file__", None)
        digest = hashlib.sha256(Path(path).read_bytes()).hexdigest() if path and Path(path).is_file() else None
        distribution = _distribution_of(target.partition(":")[0].split(".")[0])
        version = importlib.metadata.version(distribution) if distribution else None
        return PluginSource(spec, target, path, digest, distribution, version)


def file_stem(spec: str) -> str:
    """A spec as a part of a file name: `my_estimator:MyFilter` -> `my_estimator.MyFilter`."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "." for ch in spec)


def import_plugin_module(module_name: str, kind: str, spec: str):
    """The module of a plugin, importable from the current directory too (as `python -m` would)."""
    if "" not in sys.path and os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        if error.name and module_name.startswith(error.name):
            raise PluginError(f"{kind} '{spec}': no module named '{error.name}' "
                              f"(is it on PYTHONPATH or installed?)") from None
        raise PluginError(f"{kind} '{spec}': importing '{module_name}' failed: {error}") from None
    except Exception as error:      # a plugin's own import-time failure, reported in one line
        raise PluginError(f"{kind} '{spec}': importing '{module_name}' failed: "
                          f"{type(error).__name__}: {error}") from None


def _distribution_of(top_level: str) -> str | None:
    names = _distributions_by_package(tuple(sys.path)).get(top_level)
    return names[0] if names else None


@cache
def _distributions_by_package(search_path: tuple[str, ...]) -> dict[str, list[str]]:
    """`importlib.metadata.packages_distributions()`, once per `search_path` (sys.path, the cache's
    key): it reads the file list of every installed distribution (0.2 s here), and a run asks for
    each of its parts."""
    return importlib.metadata.packages_distributions()
