"""The one exception root of aeromanip and its few children."""


class AeromanipError(Exception):
    """Root of every error raised on purpose by aeromanip."""


class ConfigError(AeromanipError, ValueError):
    """An invalid robot description, scenario or option; the message names the key path."""


class InfeasibleProblemError(AeromanipError):
    """A problem whose constraints cannot all hold, detected before solving."""


class StateError(AeromanipError, ValueError):
    """A state given to the controller or simulator is malformed (NaN, wrong length)."""
