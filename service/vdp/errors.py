"""One exception hierarchy for the whole package.

Every error vdp raises on purpose derives from :class:`VdpError`, so the CLI
and the API can turn it into a one-line message instead of a traceback.
"""


class VdpError(Exception):
    """Base of every error vdp raises on purpose."""


class ConfigError(VdpError):
    """A config or profile file is wrong; the message names the file and key."""


class ProfileError(ConfigError):
    """A vehicle profile does not fit its DBC or has an invalid entry."""


class LogFormatError(VdpError):
    """A log file is missing, empty, truncated or not in a readable format."""


class BusError(VdpError):
    """The CAN bus could not be opened or failed while receiving."""


class FilterError(VdpError):
    """A filter step failed (non-finite state, covariance not positive definite)."""


class StoreError(VdpError):
    """The estimate store is unusable or belongs to another profile or schema."""


class StoreDamaged(StoreError):
    """SQLite found the store's file damaged while the service used it (Store.recover() moves it aside)."""
