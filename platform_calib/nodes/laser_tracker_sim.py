"""laser_tracker_sim: a simulated laser tracker measuring the platform's planar pose.

It reads the true pose from ``/sim/truth/platform_pose`` and adds its noise
(``position_noise`` m and ``angle_noise`` rad per axis, 10 um and 20 urad by default).
Service ``laser_tracker/measure`` (MeasurePose) waits for a pose published since
``not_before`` and answers with the measured pose (rotation about z only). With
``description`` (a machine description YAML) its noise is the described instrument's.
"""
import threading

import numpy as np
from alignment_msgs.srv import MeasurePose
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.time import Time
from std_msgs.msg import Header

from calib_core.nodes.calibrator import READ_ONLY
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.spin import run_node
from platform_calib.core.description import read_description
from platform_calib.nodes.conversions import planar_pose_as_message, planar_pose_from_message


class LaserTrackerSimNode(Node):

    def __init__(self):
        super().__init__('laser_tracker_sim')
        self.declare_parameter('position_noise', 10e-6)
        self.declare_parameter('angle_noise', 20e-6)
        self.declare_parameter('seed', 2)
        self.declare_parameter('wait_timeout_s', 2.0)
        self.declare_parameter('description', '', READ_ONLY)   # its instrument's noise wins
        g = lambda n: self.get_parameter(n).value  # noqa: E731
        if g('position_noise') < 0 or g('angle_noise') < 0 or not g('wait_timeout_s') > 0:
            raise ValueError('noise must be >= 0 and wait_timeout_s > 0')
        self.noise = np.array([g('position_noise'), g('position_noise'), g('angle_noise')])
        if g('description'):    # the user's tracker, as their machine description declares it
            instrument = read_description(g('description')).measurement.instrument
            self.noise = np.array([instrument.position_sigma_m] * 2
                                  + [instrument.angle_sigma_rad])
        self.rng = np.random.default_rng(int(g('seed')))
        self.timeout = float(g('wait_timeout_s'))
        self._truth = None
        self._changed = threading.Condition()
        self.create_subscription(PoseStamped, '/sim/truth/platform_pose', self.on_truth,
                                 LATCHED, callback_group=MutuallyExclusiveCallbackGroup())
        self.create_service(MeasurePose, 'laser_tracker/measure', self.on_measure,
                            callback_group=ReentrantCallbackGroup(), qos_profile=SERVICES)

    def on_truth(self, msg):
        with self._changed:
            self._truth = msg
            self._changed.notify_all()

    def on_measure(self, request, response):
        not_before = Time.from_msg(request.not_before)

        def ready():
            return (self._truth is not None
                    and Time.from_msg(self._truth.header.stamp) >= not_before)
        with self._changed:
            if not self._changed.wait_for(ready, timeout=self.timeout):
                response.success = False
                response.message = f'no platform pose since the request within {self.timeout:.1f} s'
                self.get_logger().error(response.message)
                return response
            truth = planar_pose_from_message(self._truth.pose)
        measured = truth + self.rng.normal(0.0, self.noise)
        msg = PoseWithCovarianceStamped(header=Header(stamp=self.get_clock().now().to_msg(),
                                                      frame_id='base'))
        msg.pose.pose = planar_pose_as_message(measured)
        covariance = np.zeros((6, 6))
        covariance[[0, 1, 5], [0, 1, 5]] = self.noise ** 2
        msg.pose.covariance = covariance.ravel().tolist()
        response.success, response.message, response.pose = True, 'ok', msg
        return response


def main(args=None):
    run_node(LaserTrackerSimNode, args, threads=2)


if __name__ == '__main__':
    main()
