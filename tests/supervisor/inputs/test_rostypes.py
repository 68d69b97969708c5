"""A recording's types (supervisor/inputs/rostypes.py, ``typestore_of``): bags that
define the same types share one store, made once, and each bag still has said for
it, under its own name, which types are decoded otherwise than it defines them."""

from __future__ import annotations

from supervisor.inputs.rostypes import typestore_of

# a recording's stub of std_msgs/msg/Float64 with other fields than the real one
OTHER = ("std_msgs/msg/Float64", "ros2msg", "float32 value")
SAME = ("std_msgs/msg/Bool", "ros2msg", "bool data")


def test_the_same_definitions_give_one_store_and_each_bag_its_own_warning() -> None:
    said_a: list[str] = []
    said_b: list[str] = []
    used = ["std_msgs/msg/Float64", "std_msgs/msg/Bool"]
    a = typestore_of([OTHER, SAME], used, said_a, "bag-a")
    b = typestore_of([OTHER, SAME], used, said_b, "bag-b")
    assert a is b  # made once
    assert len(said_a) == len(said_b) == 1
    assert said_a[0].startswith("warning: bag-a: type std_msgs/msg/Float64: ")
    assert said_b[0] == said_a[0].replace("bag-a", "bag-b", 1)
    fields = dict(a.fielddefs["std_msgs/msg/Float64"][1])
    assert list(fields) == ["data"]  # decoded as the real type, not the stub
    # other definitions: another store
    other = typestore_of([SAME], ["std_msgs/msg/Bool"], [], "bag-c")
    assert other is not a and "std_msgs/msg/Float64" not in other.fielddefs
