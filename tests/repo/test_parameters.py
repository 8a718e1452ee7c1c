"""The nodes' parameter tables (rrg_common.ros.parameters): a Param's descriptor carries its
description, read-only flag and range; declare() puts a table on a node and refuses a string
outside its choices; every node module's table is valid."""

from __future__ import annotations

import importlib

import pytest
import rclpy
from rclpy.parameter import Parameter
from repo_layout import NODE_MODULES

from rrg_common.ros.parameters import Param, declare

TABLE = (
    Param("timeout", 30.0, "Longest wait [s]", low=0.1, high=600.0),
    Param("count", 300, "Points drawn", read_only=True, low=1, high=10000),
    Param("sign", 1, "Sign", low=-1, high=1, step=2),
    Param(
        "source", "rdt", "Where the wrenches come from", read_only=True, choices=("rdt", "topics")
    ),
    Param("hosts", ["a", "b"], "Addresses"),
)


def test_a_params_descriptor_has_its_range_by_type():
    timeout, count, sign, source, hosts = (p.descriptor() for p in TABLE)
    assert (timeout.floating_point_range[0].from_value, timeout.integer_range) == (0.1, [])
    assert (count.integer_range[0].to_value, count.read_only, count.floating_point_range) == (
        10000,
        True,
        [],
    )
    assert sign.integer_range[0].step == 2
    assert source.description == "Where the wrenches come from (one of rdt, topics)"
    assert not (hosts.integer_range or hosts.floating_point_range or hosts.read_only)
    with pytest.raises(TypeError, match="needs a number"):
        Param("flag", True, "A flag", low=0, high=1).descriptor()


def _node(ros_domain: int, overrides: list[Parameter]):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain)
    node = rclpy.create_node("params_test", context=context, parameter_overrides=overrides)
    return context, node


def test_declare_puts_the_table_on_the_node_and_refuses_an_unknown_choice(ros_domain):
    context, node = _node(ros_domain, [Parameter("count", value=5)])
    try:
        declare(node, TABLE)
        assert node.get_parameter("count").value == 5
        assert node.get_parameter("hosts").value == ["a", "b"]
        (d,) = node.describe_parameters(["timeout"])
        assert d.floating_point_range[0].to_value == 600.0
        assert not node.set_parameters([Parameter("timeout", value=900.0)])[0].successful
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    context, node = _node(ros_domain, [Parameter("source", value="serial")])
    try:
        with pytest.raises(ValueError, match=r"source must be one of \('rdt', 'topics'\)"):
            declare(node, TABLE)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize("module", NODE_MODULES)
def test_every_nodes_table_is_valid(module):
    table = importlib.import_module(module).PARAMETERS
    names = [p.name for p in table]
    assert len(names) == len(set(names)) and names
    for p in table:
        assert p.description, p.name
        p.descriptor()
        if p.low is not None and not isinstance(p.default, type):
            assert p.low <= p.default <= p.high, p.name
        if p.choices:
            assert p.default in p.choices, p.name
