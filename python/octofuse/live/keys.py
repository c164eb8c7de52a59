"""The Zenoh key layout of a live fleet.

Between agents (payload: one message frame, :mod:`octofuse.fusion.wire`)::

    octofuse/<fleet>/<rule>/msg/<receiver>/<sender>     a message of one link and direction
    octofuse/<fleet>/<rule>/alive/<agent>               liveliness: the agent listens
    octofuse/<fleet>/<rule>/done/<agent>                liveliness: it has sent all it will
    octofuse/<fleet>/<rule>/status/<agent>              JSON: scans, messages, link states

What ROS 2 sees behind zenoh-bridge-ros2dds (key = the topic without its leading slash,
payload = the message's CDR bytes)::

    <agent>/octomap_full                octomap_msgs/msg/Octomap of the agent's fused map, every
                                        live.map_period seconds and at the end
    <agent>/octomap_point_cloud_centers sensor_msgs/msg/PointCloud2 of its occupied voxels
    (with several rules: <agent>/<rule>/octomap_full, ...)
    <scan topic>, tf, tf_static         what the agent maps when it is fed by the bridge
"""

from __future__ import annotations

PREFIX = "octofuse"


def message(fleet: str, rule: str, receiver: str, sender: str) -> str:
    return f"{PREFIX}/{fleet}/{rule}/msg/{receiver}/{sender}"


def inbox(fleet: str, rule: str, receiver: str) -> str:
    """Every message to ``receiver``."""
    return f"{PREFIX}/{fleet}/{rule}/msg/{receiver}/*"


def sender_of(key: str) -> str:
    """The sender named by a message key."""
    return str(key).rsplit("/", 1)[-1]


def alive(fleet: str, rule: str, agent: str) -> str:
    return f"{PREFIX}/{fleet}/{rule}/alive/{agent}"


def done(fleet: str, rule: str, agent: str) -> str:
    """Liveliness: the agent has sent everything it will (it still listens)."""
    return f"{PREFIX}/{fleet}/{rule}/done/{agent}"


def status(fleet: str, rule: str, agent: str) -> str:
    return f"{PREFIX}/{fleet}/{rule}/status/{agent}"


def statuses(fleet: str) -> str:
    return f"{PREFIX}/{fleet}/*/status/*"


def ros_topic_key(topic: str) -> str:
    """A ROS 2 topic's key as zenoh-bridge-ros2dds publishes it."""
    return topic.lstrip("/")


def fused_map(agent: str, rule: str | None = None) -> str:
    """The agent's fused map; ``rule`` names it when a fleet runs several."""
    return f"{agent}/{rule}/octomap_full" if rule else f"{agent}/octomap_full"


def occupied_cloud(agent: str, rule: str | None = None) -> str:
    return (
        f"{agent}/{rule}/octomap_point_cloud_centers"
        if rule
        else f"{agent}/octomap_point_cloud_centers"
    )
