"""Copies of a recorded bag, written by the package's own `BagWriter`, with chosen parts changed:
the tests' way to make altered or damaged bags that are otherwise well-formed."""
from pathlib import Path

from mobile_manip_sim.recording.bag_reader import open_bag
from mobile_manip_sim.recording.bag_writer import BagWriter


def rewrite_bag(source: Path, target: Path, transform=None, *, metadata=None, attachments=None,
                qos=None) -> None:
    """Copy a bag, passing each message through transform(topic, data, index); `metadata` and
    `attachments` (name → new value, None = leave out) replace the recorded ones, `qos` (topic →
    offered_qos_profiles text) the recorded QoS."""
    bag = open_bag(source)
    offered = {topic: channel["offered_qos_profiles"]
               for topic, channel in bag.channel_metadata().items()}
    offered.update(qos or {})
    counts = {}
    with BagWriter(target) as writer:
        for topic, type_name in bag.topics().items():
            writer.add_topic(topic, type_name, offered[topic])
        for name, data in {**bag.attachments(), **(attachments or {})}.items():
            if data is not None:
                writer.add_attachment(name, "application/octet-stream", data)
        for name, data in {**bag.metadata(), **(metadata or {})}.items():
            if name != "rosbag2" and data is not None:
                writer.add_metadata(name, data)
        for message in bag.messages():
            index = counts[message.topic] = counts.get(message.topic, -1) + 1
            data = (message.data if transform is None
                    else transform(message.topic, message.data, index))
            writer.write(message.topic, data, message.log_time_ns, message.publish_time_ns)
