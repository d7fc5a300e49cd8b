"""Errors that the CLI reports as one line on stderr with exit code 2."""


class UserError(Exception):
    """Bad input from the user: unknown names, out-of-range numbers, missing or corrupt files."""


class ConfigError(UserError):
    """A configuration value or file is invalid."""


class SimulationDiverged(RuntimeError):
    """The simulation state became non-finite."""


class PluginError(ConfigError):
    """A part named by a spec (estimator, controller, terrain, ...) cannot be found, imported or built."""


class PluginFailure(RuntimeError):
    """A part failed while the run was going on (it raised, or returned something malformed)."""
