"""Tether: a ROS-free robotics middleware (typed msgpack over ZeroMQ, YAML launch, MCAP logs)."""
from tether.errors import ConfigError, DecodeError, DriverError, TetherError
from tether.message import Message, message_type, registered_types
from tether.node import (Input, NoConfig, Node, NonNegativeFloat, NonNegativeInt, PositiveFloat, PositiveInt,
                         Tick)

__all__ = ["ConfigError", "DecodeError", "DriverError", "Input", "Message", "NoConfig", "Node", "NonNegativeFloat",
           "NonNegativeInt", "PositiveFloat", "PositiveInt", "TetherError", "Tick", "message_type", "registered_types"]
__version__ = "0.1.0"
