"""Exception hierarchy of the companion. Messages say what was wrong and where."""


class CompanionError(Exception):
    """Base of every error the companion raises on purpose."""


class ConfigError(CompanionError, ValueError):
    """A configuration file or value is invalid (the message names file, key and value)."""


class InputError(CompanionError, ValueError):
    """An array handed to a pure core has the wrong shape, is not finite, or is not a valid covariance."""


class LinkError(CompanionError, RuntimeError):
    """The MAVLink link could not be opened or was lost."""
