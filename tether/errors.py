"""The runtime's small exception tree."""


class TetherError(Exception):
    """Base of every error the runtime raises on purpose."""


class ConfigError(TetherError):
    """A launch file, node Config or command-line parameter is wrong."""


class DecodeError(TetherError):
    """A frame or log record is not a valid message of the expected type."""


class DriverError(TetherError):
    """Hardware I/O failed (connection lost, protocol violated, device fault)."""
