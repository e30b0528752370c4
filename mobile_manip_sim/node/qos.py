"""The node's publishers with rclpy's standard QoS overrides: every published topic declares the
read-only parameters ``qos_overrides.<topic>.publisher.{history,depth,reliability}``
(`QoSOverridingOptions.with_default_policies`, as rclpy and rclcpp nodes do; ``<topic>`` is the
resolved name, ``/robot1/odom`` under a namespace). Their values are checked here like every other
parameter — a bad one, or one for a topic the node does not publish, is a `UserError` naming it —
because rclpy would fail with a traceback or take them silently."""
from __future__ import annotations

from rclpy.qos_overriding_options import QoSOverridingOptions

from ..ros.topics import relative
from ..scene.errors import UserError
from ..scene.limits import QOS_DEPTH

QOS_OVERRIDES = "qos_overrides."
# The policies with_default_policies declares and the values rclpy takes for each.
CHOICES = {"history": ("keep_last", "keep_all", "system_default"),
           "reliability": ("reliable", "best_effort", "best_available", "system_default")}
DEPTH = "depth"


def publisher(node, kind, topic: str, qos, absolute: bool = False):
    """``node``'s publisher of ``kind`` on ``topic`` (topics.py's canonical name; created under
    its relative name unless ``absolute``) with ``qos``, which the overrides may change."""
    name = topic if absolute else relative(topic)
    _check(node, node.resolve_topic_name(name))
    return node.create_publisher(kind, name, qos,
                                 qos_overriding_options=QoSOverridingOptions.
                                 with_default_policies())


def _check(node, resolved: str) -> None:
    for policy in (*CHOICES, DEPTH):
        key = f"{QOS_OVERRIDES}{resolved}.publisher.{policy}"
        override = node._parameter_overrides.get(key)
        if override is None:
            continue
        value = override.value
        if policy == DEPTH:
            low, high = QOS_DEPTH
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise UserError(key, f"expected an integer from {low} to {high}, got {value!r}")
        elif value not in CHOICES[policy]:
            raise UserError(key, f"expected one of {', '.join(CHOICES[policy])}, got {value!r}")


def check_unknown(node) -> None:
    """After every publisher exists: an override no publisher declared is a mistake (a typo, a
    topic the node does not publish, or a subscription's)."""
    declared = node._parameters
    unknown = sorted(name for name in node._parameter_overrides
                     if name.startswith(QOS_OVERRIDES) and name not in declared)
    if unknown:
        topics = sorted({name[len(QOS_OVERRIDES):].rsplit(".publisher.", 1)[0]
                         for name in declared if name.startswith(QOS_OVERRIDES)})
        raise UserError(unknown[0], f"unknown QoS override (the node publishes "
                                    f"{', '.join(topics)}; each takes qos_overrides.<topic>."
                                    f"publisher.history, .depth and .reliability)")
