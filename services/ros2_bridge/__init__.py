"""ROS 2 over Zenoh with no ROS installation: rmw_zenoh's keys, attachments and discovery
tokens (``rmw``), Shepherd <-> ROS 2 messages through rosbags (``convert``); ``service`` is
the bridge on the bus."""

from services.ros2_bridge.rmw import data_key, entity_token, node_token, pack_attachment

__all__ = ["data_key", "entity_token", "node_token", "pack_attachment"]
