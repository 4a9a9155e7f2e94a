"""player: replays a rosbag2 MCAP bag onto its topics (CDR bytes, original timing).

Parameters: ``bag`` (directory), ``rate`` (time scale, 1.0 = recorded speed), ``topics``
(empty: all). Latched topics ending in ``/result`` are republished TRANSIENT_LOCAL so late
subscribers still get them. The node logs and stops playing on a damaged bag; it exits
when playback ends.
"""
import time

import rclpy
from rclpy.node import Node

from calib_core.bags import bag_topics, read_bag
from calib_core.errors import MachineAlignmentError
from calib_core.nodes.qos import LATCHED
from calib_core.nodes.spin import run_node
from calib_core.nodes.types import message_class


class PlayerNode(Node):

    def __init__(self):
        super().__init__('player')
        self.declare_parameter('bag', '')
        self.declare_parameter('rate', 1.0)
        self.declare_parameter('topics', [''])
        self.declare_parameter('start_delay_s', 1.0)
        self.path = self.get_parameter('bag').value
        self.rate = float(self.get_parameter('rate').value)
        if not self.path or self.rate <= 0:
            raise ValueError('set parameter bag to a bag directory and rate > 0')
        self.topics = [t for t in self.get_parameter('topics').value if t] or None
        # Publishers exist before playback so recorders and subscribers can discover them.
        self.publishers_by_topic = {
            topic: self.create_publisher(message_class(msgtype), topic,
                                         LATCHED if topic.endswith('/result') else 10)
            for topic, msgtype in bag_topics(self.path).items()
            if self.topics is None or topic in self.topics}
        self.done = False
        self.create_timer(float(self.get_parameter('start_delay_s').value), self.play)

    def play(self):
        if self.done:
            return
        self.done = True
        start_wall, start_bag, count = time.monotonic(), None, 0
        try:
            for topic, _, stamp, raw in read_bag(self.path, self.topics):
                start_bag = stamp if start_bag is None else start_bag
                delay = (stamp - start_bag) * 1e-9 / self.rate - (time.monotonic() - start_wall)
                if delay > 0:
                    time.sleep(delay)
                self.publishers_by_topic[topic].publish(raw)
                count += 1
            self.get_logger().info(f'played {count} messages from {self.path}')
        except MachineAlignmentError as exc:
            self.get_logger().error(f'playback stopped after {count} messages: {exc}')
        time.sleep(1.0)  # let reliable subscribers receive the tail before exiting
        raise SystemExit(0)


def main(args=None):
    try:
        run_node(PlayerNode, args)
    except SystemExit:
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
