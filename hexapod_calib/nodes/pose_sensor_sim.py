"""pose_sensor_sim: a simulated CMM / laser tracker that measures the hexapod platform pose.

It reads the true pose from ``/sim/truth/hexapod_pose`` (as a real instrument sees the real
platform) and adds its measurement noise (0.6 um and 6 urad per axis by default). Service
``pose_sensor/measure`` (MeasurePose) waits for a platform at rest since ``not_before`` and
answers with the measured pose; each measurement is also published on ``/pose_sensor/pose``.
With ``description`` (a machine description YAML) its noise is the described instrument's.
"""
import threading


from alignment_msgs.srv import MeasurePose
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.time import Time
from std_msgs.msg import Header

from calib_core.errors import InvalidInputError, MachineAlignmentError
from calib_core.nodes.calibrator import READ_ONLY
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.spin import run_node
from hexapod_calib.core.description import read_description
from hexapod_calib.core.records import pose_from_message
from hexapod_calib.nodes.conversions import pose_as_message
from hexapod_calib.sim.hexapod import PoseSensorSim


class PoseSensorSimNode(Node):

    def __init__(self):
        super().__init__('pose_sensor_sim')
        self.declare_parameter('position_noise', 0.6e-6, READ_ONLY)
        self.declare_parameter('angle_noise', 6e-6, READ_ONLY)
        self.declare_parameter('description', '', READ_ONLY)   # its instrument's noise wins
        self.declare_parameter('seed', 1, READ_ONLY)
        self.declare_parameter('wait_timeout_s', 2.0)
        noise = (float(self.get_parameter('position_noise').value),
                 float(self.get_parameter('angle_noise').value))
        described = self.get_parameter('description').value
        if described:       # the user's instrument, as their machine description declares it
            instrument = read_description(described).measurement.instrument
            noise = (instrument.position_sigma_m, instrument.angle_sigma_rad)
        self.sensor = PoseSensorSim(*noise, int(self.get_parameter('seed').value))
        self.timeout = float(self.get_parameter('wait_timeout_s').value)
        self._truth = None
        self._changed = threading.Condition()
        self.create_subscription(PoseStamped, '/sim/truth/hexapod_pose', self.on_truth, LATCHED,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, '/pose_sensor/pose', 10)
        self.create_service(MeasurePose, 'pose_sensor/measure', self.on_measure,
                            callback_group=ReentrantCallbackGroup(), qos_profile=SERVICES)

    def on_truth(self, msg):
        with self._changed:
            self._truth = msg
            self._changed.notify_all()

    def _at_rest_since(self, not_before: Time):
        def ready():
            return self._truth is not None and Time.from_msg(self._truth.header.stamp) >= not_before
        with self._changed:
            if not self._changed.wait_for(ready, timeout=self.timeout):
                raise MachineAlignmentError('no platform at rest to measure (no pose from the '
                                            f'hexapod within {self.timeout:.1f} s)')
            return pose_from_message(self._truth.pose)

    def on_measure(self, request, response):
        try:
            true_pose = self._at_rest_since(Time.from_msg(request.not_before))
            measured = self.sensor.measure(true_pose)
        except (MachineAlignmentError, InvalidInputError) as exc:
            self.get_logger().error(f'measurement failed: {exc}')
            response.success, response.message = False, str(exc)
            return response
        msg = PoseWithCovarianceStamped(header=Header(stamp=self.get_clock().now().to_msg(),
                                                      frame_id='base'))
        msg.pose.pose = pose_as_message(measured)
        msg.pose.covariance = self.sensor.covariance().ravel().tolist()
        self.pose_pub.publish(msg)
        response.success, response.message, response.pose = True, 'ok', msg
        return response


def main(args=None):
    run_node(PoseSensorSimNode, args, threads=2)


if __name__ == '__main__':
    main()
