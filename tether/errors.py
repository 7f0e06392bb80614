"""The runtime's small exception tree."""


class TetherError(Exception):
    """Base of every error the runtime raises on purpose."""


class ConfigError(TetherError):
    """A launch file, node Config or command-line parameter is wrong.

    ``key`` names the offending parameter when there is one, so a launch file can point
    at its line.
    """

    def __init__(self, message: str, *, key: str = "") -> None:
        super().__init__(message)
        self.key = key


class DecodeError(TetherError):
    """A frame or log record is not a valid message of the expected type."""


class DriverError(TetherError):
    """Hardware I/O failed (connection lost, protocol violated, device fault)."""
