"""The message base: frozen, keyword-only msgspec Structs tagged ``"<domain>.<Name>"``.

Every message carries the header fields ``stamp_ns`` (when the data was acquired),
``frame_id`` and ``seq`` (stamped by the publisher, per topic).  Array fields are
annotated ``numpy.ndarray`` and handled by :mod:`tether.codec`.

Schema evolution policy: only append fields, with defaults; never change a field's
type or reuse a tag.  Logs carry each type's JSON schema.
"""
from __future__ import annotations

import importlib

import msgspec
import numpy as np


class Message(msgspec.Struct, frozen=True, kw_only=True, tag_field="type"):
    """Base of every tether message.

    Subclasses give their tag explicitly::

        class Pose2D(Message, tag="geometry.Pose2D"):
            x_m: float = 0.0
    """

    stamp_ns: int = 0
    frame_id: str = ""
    seq: int = 0

    @classmethod
    def type_name(cls) -> str:
        """The tag, e.g. ``"sonar.SonarPing"``."""
        return cls.__struct_config__.tag  # type: ignore[return-value]

    @classmethod
    def domain(cls) -> str:
        """The part of the tag before the dot, e.g. ``"sonar"``."""
        return cls.type_name().split(".", 1)[0]


def registered_types() -> dict[str, type[Message]]:
    """Every message class imported so far, by tag.

    Raises ``TypeError`` when a class has no tag of its own or two classes share one.
    """
    found: dict[str, type[Message]] = {}
    stack = list(Message.__subclasses__())
    while stack:
        cls = stack.pop()
        stack.extend(cls.__subclasses__())
        tag = cls.__struct_config__.tag
        parent_tags = {b.__struct_config__.tag for b in cls.__bases__ if issubclass(b, msgspec.Struct)}
        if not isinstance(tag, str) or tag.count(".") != 1 or tag in parent_tags:
            raise TypeError(f"{cls.__module__}.{cls.__qualname__}: give the message a tag of its own "
                            f"'<domain>.<Name>', e.g. class {cls.__name__}(Message, tag='std.{cls.__name__}')")
        other = found.get(tag)
        if other is not None and other is not cls:
            raise TypeError(f"message tag {tag!r} is used by both {other.__module__}.{other.__qualname__} "
                            f"and {cls.__module__}.{cls.__qualname__}; tags are never reused")
        found[tag] = cls
    return found


def message_type(tag: str) -> type[Message]:
    """Look up a message class by tag, importing ``msgs.<domain>`` on demand."""
    types = registered_types()
    if tag not in types:
        try:
            importlib.import_module(f"msgs.{tag.split('.', 1)[0]}")
        except ImportError:
            pass
        types = registered_types()
    try:
        return types[tag]
    except KeyError:
        raise KeyError(f"unknown message type {tag!r} (no msgs.{tag.split('.', 1)[0]} module defines it)") from None


def const(array: "np.ndarray") -> "np.ndarray":
    """Mark an array read-only; use for array defaults, which every instance shares."""
    array.flags.writeable = False
    return array
