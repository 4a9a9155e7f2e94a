"""recorder: records chosen topics to an MCAP bag in rosbag2 layout.

Parameters: ``topics`` (names to record; types are discovered on the graph), ``output``
(bag directory, must not exist). Messages are stored as received (CDR bytes). The bag is
closed, with its metadata.yaml, when the node shuts down.
"""
from datetime import datetime, timezone

from rclpy.node import Node

from calib_core.bags import BagWriter
from calib_core.errors import MachineAlignmentError
from calib_core.nodes.spin import run_node
from calib_core.nodes.types import message_class


class RecorderNode(Node):

    def __init__(self):
        super().__init__('recorder')
        stamp = datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%S')
        self.declare_parameter('topics', ['/vision_calibrator/observations',
                                          '/vision_calibrator/result', '/marks'])
        self.declare_parameter('output', f'runs/recording_{stamp}')
        self.wanted = list(self.get_parameter('topics').value)
        if not self.wanted:
            raise ValueError('parameter topics is empty: nothing to record')
        self.bag = BagWriter(self.get_parameter('output').value).__enter__()
        self.subscriptions_by_topic = {}
        self.count = 0
        self.create_timer(0.5, self.discover)
        self.get_logger().info(f'recording {self.wanted} to {self.bag.path}')

    def discover(self):
        for topic, types in self.get_topic_names_and_types():
            if topic not in self.wanted or topic in self.subscriptions_by_topic:
                continue
            try:
                msgtype = types[0]
                self.bag.add_topic(topic, msgtype)
                self.subscriptions_by_topic[topic] = self.create_subscription(
                    message_class(msgtype), topic, lambda raw, t=topic: self.record(t, raw), 10,
                    raw=True)
                self.get_logger().info(f'recording {topic} ({msgtype})')
            except MachineAlignmentError as exc:
                self.get_logger().error(f'cannot record {topic}: {exc}')

    def record(self, topic, raw: bytes):
        self.bag.write(topic, self.get_clock().now().nanoseconds, raw)
        self.count += 1

    def destroy_node(self):
        self.bag.close()
        self.get_logger().info(f'wrote {self.count} messages to {self.bag.path}')
        return super().destroy_node()


def main(args=None):
    run_node(RecorderNode, args)


if __name__ == '__main__':
    main()
