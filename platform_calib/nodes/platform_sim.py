"""platform_sim: the simulated screen-registration platform (3-PRR) with true parameter
errors (``scale`` of 0.2-1 mm and 0.5 deg), optional ball-screw periodic error and
backlash per feed, and the camera system that measures the screen's two marks.

Service ``platform/move`` (MovePlatform) drives the three feeds (refused outside the
stroke: nothing moves) and answers with the feed sensors' reading; ``platform/measure_marks``
(MeasureMarks) returns the two marks in the base frame with ``mark_noise``; the screen is
mounted on the platform at ``screen_pose`` (x m, y m, theta rad). Truth on
``/sim/truth/platform_pose`` (latched) for the laser tracker simulation. With
``description`` (a machine description YAML, docs/machine_description.md) it simulates the
user's platform: the described nominal geometry with the same kind of true errors, and
its feeds' noise and repeatability.
"""
import threading

import numpy as np
from alignment_msgs.srv import MeasureMarks, MovePlatform
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from calib_core.errors import MachineAlignmentError
from calib_core.frames import planar
from calib_core.nodes.calibrator import READ_ONLY
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.scene import TF_TOPIC, transform_message
from calib_core.nodes.spin import run_node
from platform_calib.core.compensation import mark_positions
from platform_calib.core.description import read_description
from platform_calib.core.registration import compose
from platform_calib.nodes.conversions import planar_pose_as_message
from platform_calib.sim.platform import PlatformSim, true_geometry


class PlatformSimNode(Node):

    def __init__(self):
        super().__init__('platform_sim')
        self.declare_parameter('seed', 0)
        self.declare_parameter('scale', 0.15)
        self.declare_parameter('screw', 0.0)
        self.declare_parameter('backlash', 0.0)
        self.declare_parameter('screen_pose', [0.8e-3, -0.5e-3, 0.0035])
        self.declare_parameter('mark_noise', 3e-6)
        self.declare_parameter('description', '', READ_ONLY)   # the user's machine description
        g = lambda n: self.get_parameter(n).value  # noqa: E731
        screen = np.asarray(g('screen_pose'), dtype=float)
        if screen.shape != (3,) or not np.all(np.isfinite(screen)) or g('mark_noise') < 0 \
                or g('scale') < 0 or g('screw') < 0 or g('backlash') < 0:
            raise ValueError('screen_pose must be (x m, y m, theta rad); scale, screw, '
                             'backlash and mark_noise must be >= 0')
        seed = int(g('seed'))
        self.screen, self.mark_noise = screen, float(g('mark_noise'))
        described = {}
        if g('description'):
            description = read_description(g('description'))
            m = description.measurement
            described = {'feed_noise': float(np.hypot(m.actuators.sigma_m, m.repeatability_m))}
            truth = true_geometry(seed, float(g('scale')), description.geometry)
        else:
            truth = true_geometry(seed, float(g('scale')))
        self.sim = PlatformSim(truth, seed, screw_amplitude=(float(g('screw')),) * 3,
                               backlash=(float(g('backlash')),) * 3, **described)
        self.rng = np.random.default_rng(seed + 31)
        self._lock = threading.Lock()
        self.truth_pub = self.create_publisher(PoseStamped, '/sim/truth/platform_pose', LATCHED)
        self.tf_pub = self.create_publisher(TFMessage, TF_TOPIC, 10)
        self.create_service(MovePlatform, 'platform/move', self.on_move, qos_profile=SERVICES)
        self.create_service(MeasureMarks, 'platform/measure_marks', self.on_marks,
                            qos_profile=SERVICES)
        self._publish_truth()

    def _publish_truth(self):
        now = self.get_clock().now()
        self.truth_pub.publish(PoseStamped(header=Header(stamp=now.to_msg(), frame_id='base'),
                                           pose=planar_pose_as_message(self.sim.pose)))
        # The platform where the simulated machine put it, under the calibrator's base.
        self.tf_pub.publish(transform_message(now.nanoseconds, [
            ('base', 'platform', *planar(*self.sim.pose))]))

    def on_move(self, request, response):
        try:
            with self._lock:
                self.sim.move(np.asarray(request.feeds, dtype=float))
                reading, direction = self.sim.read_feeds(), self.sim.direction
        except MachineAlignmentError as exc:
            self.get_logger().error(f'move refused: {exc}')
            response.success, response.message = False, str(exc)
            return response
        self._publish_truth()
        response.success, response.message = True, 'ok'
        response.feeds = [float(v) for v in reading]
        response.direction = [int(v) for v in direction]
        return response

    def on_marks(self, request, response):
        with self._lock:
            marks = mark_positions(compose(self.sim.pose, self.screen)[None])[0]
        marks = marks + self.rng.normal(0.0, self.mark_noise, marks.shape)
        response.success, response.message = True, 'ok'
        response.marks = [float(v) for v in marks.ravel()]
        return response


def main(args=None):
    run_node(PlatformSimNode, args)


if __name__ == '__main__':
    main()
