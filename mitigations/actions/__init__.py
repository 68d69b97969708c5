"""The mitigation actions, and :func:`build_action`, which makes one from its settings.

To add an action kind: give it a settings dataclass, keys and checks in
:mod:`mitigations.settings` (``MITIGATION_KINDS``, ``SETTING_KEYS``), write a
module here whose class implements :class:`mitigations.actions.base.Action`
and takes the typed settings, and add a branch to :func:`build_action`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from mitigations.actions.base import Action
from mitigations.settings import (
    CommandSettings,
    LogSettings,
    Mitigation,
    PublishSettings,
    SshSettings,
)

if TYPE_CHECKING:
    from rclpy.node import Node

    from mitigations.actions.publish import PublishAction

# A publisher is shared by publish actions with the same (topic, message type, QoS).
PublisherKey = tuple[str, str, str]


def build_action(
    mitigation: Mitigation, node: Node, publishers: dict[PublisherKey, PublishAction]
) -> Action:
    """The action of ``mitigation``.  ``publishers``: the publish actions built so far
    (kept by the caller across config reloads); a new publish action takes over the
    publisher of one with the same key, so the halt it latched stays latched."""
    name, s = mitigation.name, mitigation.settings
    if isinstance(s, PublishSettings):
        # rclpy only here: check and the tools import this package without a ROS node.
        from mitigations.actions.publish import PublishAction

        key = (s.topic, s.msg, s.qos)
        action = PublishAction(node, name, s, publishers.get(key))
        publishers[key] = action
        return action
    # Each kind loads when a mitigation of it is built (paramiko only for ssh):
    # the CLI, check and the daemon core import this package without them.
    if isinstance(s, SshSettings):
        from mitigations.actions.ssh import SshAction

        return SshAction(name, s)
    if isinstance(s, CommandSettings):
        from mitigations.actions.command import CommandAction

        return CommandAction(name, s)
    if isinstance(s, LogSettings):
        from mitigations.actions.log import LogAction

        return LogAction(name, s)
    raise TypeError(f"mitigation '{name}': no action for {type(s).__name__}")
