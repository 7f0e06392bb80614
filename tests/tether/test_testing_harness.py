"""tether.testing: deterministic in-process runs with timers on a virtual clock."""
from __future__ import annotations

import msgspec
import pytest

from msgs.std import Float64
from nodes.std.demo import Counter, Scale
from tether import Node
from tether.errors import ConfigError
from tether.testing import Harness, run_node


def test_timer_node_fires_at_virtual_times() -> None:
    with Harness(Counter, params={"rate_hz": 10}) as h:
        outs = h.advance_to(0.95)
    assert [o.t_ns for o in outs] == [i * 100_000_000 for i in range(10)]
    assert [o.msg.data for o in outs] == [float(i) for i in range(10)]
    assert [o.msg.seq for o in outs] == list(range(1, 11))


def test_inputs_and_timers_interleave_in_time_order() -> None:
    class Both(Node):
        inputs = {"value": Float64}
        outputs = {"log": Float64}
        timers = {"tick": 4.0}

        def on_value(self, msg: Float64) -> dict:
            return {"log": Float64(data=msg.data)}

        def on_tick(self, tick) -> dict:
            return {"log": Float64(data=-1.0)}

    outs = run_node(Both, [(0.3, "value", Float64(data=1.0)), (0.1, "value", Float64(data=2.0))], until_s=0.6)
    assert [o.msg.data for o in outs] == [-1.0, 2.0, -1.0, 1.0, -1.0]


def test_handler_errors_propagate_or_are_counted() -> None:
    events = [(0.0, "value", Float64(data=1.0)), (0.1, "value", Float64(data=5.0)), (0.2, "value", Float64(data=2.0))]
    with pytest.raises(ValueError, match="injected"):
        run_node(Scale, events, params={"fail_on": 5.0})
    h = Harness(Scale, params={"fail_on": 5.0}, catch_errors=True)
    outs = h.feed(events)
    assert [o.msg.data for o in outs] == [2.0, 4.0] and len(h.errors) == 1


def test_wrong_input_type_and_bad_params_are_refused() -> None:
    with pytest.raises(ConfigError, match="gain"):
        Harness(Scale, params={"gain": "lots"})
    from msgs.std import String
    with pytest.raises(TypeError, match="takes Float64"):
        Harness(Scale).feed([(0.0, "value", String(data="x"))])


def test_input_without_handler_is_a_config_error() -> None:
    class Broken(Node):
        inputs = {"value": Float64}

    with pytest.raises(ConfigError, match="on_value"):
        Harness(Broken)


def test_publishing_an_undeclared_type_fails_loudly() -> None:
    class Liar(Node):
        class Config(msgspec.Struct, frozen=True):
            pass
        inputs = {"value": Float64}
        outputs = {"out": Float64}

        def on_value(self, msg):
            from msgs.std import String
            return {"out": String(data="no")}

    with pytest.raises(TypeError, match="declared Float64"):
        run_node(Liar, [(0.0, "value", Float64())])
