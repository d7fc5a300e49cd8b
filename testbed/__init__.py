"""Hexapod control and sensor-fusion testbed.

`import testbed` stays light, for every layer below imports it: the public names load on first
use (PEP 562): `testbed.run`, `testbed.load`, `testbed.replay`, `testbed.Result`, `testbed.Dataset`
(testbed/api.py), `testbed.Controller`, `testbed.Terrain`, `testbed.ContactModel` and `testbed.PostureLaw`.

It also registers the gymnasium environment `HexapodTestbed-v0` (testbed/gym_env.py) without
importing gymnasium (a tenth of a second): at once when gymnasium is already imported, else the
moment it is, through a finder on `sys.meta_path` that runs the registration after gymnasium's
own `__init__` (gymnasium 1.x loads no plugins by itself).
"""

import sys
from importlib import import_module
from importlib.util import find_spec

from testbed import numba_cache

numba_cache.configure()     # before any kernel module imports numba

_EXPORTS = {
    "run": "testbed.api", "load": "testbed.api", "replay": "testbed.api", "Result": "testbed.api",
    "Dataset": "testbed.api",
    "Controller": "testbed.control.controller",
    "Terrain": "testbed.world.terrain",
    "ContactModel": "testbed.world.contact",
    "PostureLaw": "testbed.control.posture",
}
GYM_ENV_ID = "HexapodTestbed-v0"
GYM_ENTRY_POINT = "testbed.gym_env:HexapodTestbedEnv"
GYM_MAX_EPISODE_STEPS = 1000    # gymnasium.make's time limit (10 s at the default control period)


def __getattr__(name):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'testbed' has no attribute {name!r}")
    return getattr(import_module(_EXPORTS[name]), name)


def __dir__():
    return sorted([*globals(), *_EXPORTS])


def register_gym_env(gymnasium) -> None:
    """Register HexapodTestbed-v0 with `gymnasium` (the module), once."""
    if GYM_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=GYM_ENV_ID, entry_point=GYM_ENTRY_POINT, max_episode_steps=GYM_MAX_EPISODE_STEPS)


class _RegisterAfterImport:
    """The loader of gymnasium's package, and then the registration."""

    def __init__(self, loader):
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        self.loader.exec_module(module)
        register_gym_env(module)

    def __getattr__(self, name):
        return getattr(self.loader, name)


class _GymnasiumFinder:
    """On `sys.meta_path` until gymnasium is imported: finds it as the other finders do, with
    its loader wrapped to register the env afterwards."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = find_spec(name)
        if spec is not None and spec.loader is not None:
            spec.loader = _RegisterAfterImport(spec.loader)
        return spec


if "gymnasium" in sys.modules:
    register_gym_env(sys.modules["gymnasium"])
elif not any(isinstance(finder, _GymnasiumFinder) for finder in sys.meta_path):
    sys.meta_path.insert(0, _GymnasiumFinder())
