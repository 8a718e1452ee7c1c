"""A node's parameters as one declarative table, declared with their descriptors by one helper.

Each node module holds a tuple of ``Param``s, as a generate_parameter_library YAML file would:
the name, the default (whose type is the parameter's), the description with its unit, whether
it is fixed at start (``read_only``), and a range or the strings it may take. ``declare`` puts
them on the node; a value outside ``choices`` is refused with ValueError, as ROS refuses one
outside a range.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node


@dataclass(frozen=True)
class Param:
    """One parameter: ``low``/``high`` bound a float or an int (``step`` for ints); ``choices``
    are the strings a string parameter may take (appended to its description)."""

    name: str
    default: object
    description: str
    read_only: bool = False
    low: float | None = None
    high: float | None = None
    step: int = 1
    choices: tuple[str, ...] = ()

    def descriptor(self) -> ParameterDescriptor:
        """The ROS descriptor: description, read-only flag and range."""
        text = self.description
        if self.choices:
            text += f" (one of {', '.join(self.choices)})"
        d = ParameterDescriptor(description=text, read_only=self.read_only)
        if self.low is not None and self.high is not None:
            if isinstance(self.default, bool) or not isinstance(self.default, int | float):
                raise TypeError(f"{self.name}: a range needs a number, not {self.default!r}")
            if isinstance(self.default, int):
                d.integer_range = [
                    IntegerRange(from_value=int(self.low), to_value=int(self.high), step=self.step)
                ]
            else:
                d.floating_point_range = [
                    FloatingPointRange(from_value=float(self.low), to_value=float(self.high))
                ]
        return d


def declare(node: Node, table: Iterable[Param]) -> None:
    """Declare every parameter of ``table`` on ``node`` with its descriptor; ValueError for a
    string parameter given a value outside its ``choices``."""
    for p in table:
        node.declare_parameter(p.name, p.default, p.descriptor())
        if p.choices:
            given = node.get_parameter(p.name).value
            if given not in p.choices:
                raise ValueError(f"{p.name} must be one of {tuple(p.choices)}, got {given!r}")
