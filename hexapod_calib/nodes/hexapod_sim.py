"""hexapod_sim: a simulated 6-SPS hexapod with true geometric errors, joint play and
actuator noise (hexapod_calib.sim.hexapod).

Service ``hexapod/move`` (MoveHexapod) moves to a pose (through the controller's nominal
inverse kinematics) or to six actuator lengths, and refuses lengths outside the stroke,
poses near a singularity and lengths no pose realises, without moving. Publishes the
commanded actuator lengths on ``/hexapod/leg_lengths`` (sensor_msgs/JointState, m) and the
true platform pose on ``/sim/truth/hexapod_pose`` (latched), which only simulated
instruments may read. With ``description`` (a machine description YAML,
docs/machine_description.md) it simulates the user's hexapod: the described nominal
geometry (with the same kind of true errors), its strokes, its home and its actuators'
noise; the description's strokes then stand for the ``stroke`` parameter.
"""
import dataclasses

import numpy as np
from alignment_msgs.srv import MoveHexapod
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from calib_core.errors import InvalidInputError, MachineAlignmentError
from calib_core.nodes.calibrator import READ_ONLY, described_machine
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.scene import TF_TOPIC, frame_of, transform_message
from calib_core.nodes.spin import run_node
from hexapod_calib.core.description import read_description
from hexapod_calib.core.geometry import nominal_geometry, read_geometry
from hexapod_calib.core.records import leg_lengths_from_message, pose_from_message
from hexapod_calib.nodes.conversions import pose_as_message
from hexapod_calib.sim.hexapod import HexapodSim, HexapodTruth, Stroke

LEG_NAMES = [f'leg{i + 1}' for i in range(6)]


class HexapodSimNode(Node):

    def __init__(self):
        super().__init__('hexapod_sim')
        self.declare_parameter('nominal_geometry', '', READ_ONLY)
        self.declare_parameter('description', '', READ_ONLY)   # the user's machine description
        self.declare_parameter('truth_seed', 2, READ_ONLY)
        self.declare_parameter('noise_seed', 0, READ_ONLY)
        self.declare_parameter('stroke', [0.17, 0.30], READ_ONLY)
        self.declare_parameter('rate_hz', 10.0)
        description, nominal = described_machine(self, read_description, read_geometry,
                                                 nominal_geometry)
        stroke = [float(v) for v in self.get_parameter('stroke').value]
        rate = float(self.get_parameter('rate_hz').value)
        if len(stroke) != 2 or not stroke[0] < stroke[1] or not rate > 0:
            raise InvalidInputError('stroke must be [min, max] (m) and rate_hz > 0')
        truth = HexapodTruth.default(nominal, int(self.get_parameter('truth_seed').value))
        home = {}
        if description is not None:
            truth = dataclasses.replace(
                truth, actuator_noise=description.measurement.actuators.sigma_m)
            if description.workspace:
                stroke = list(description.workspace['stroke'])
                home = {'home': description.workspace['home']}
        self.sim = HexapodSim(truth, nominal, Stroke(*stroke),
                              seed=int(self.get_parameter('noise_seed').value), **home)
        self.legs_pub = self.create_publisher(JointState, '/hexapod/leg_lengths', 10)
        self.truth_pub = self.create_publisher(PoseStamped, '/sim/truth/hexapod_pose', LATCHED)
        self.tf_pub = self.create_publisher(TFMessage, TF_TOPIC, 10)
        self.create_service(MoveHexapod, 'hexapod/move', self.on_move, qos_profile=SERVICES)
        self.create_timer(1.0 / rate, self.publish_legs)
        self._settled = self.get_clock().now().to_msg()
        self.publish_truth()

    def publish_legs(self):
        now = self.get_clock().now()
        self.legs_pub.publish(JointState(header=Header(stamp=now.to_msg()),
                                         name=LEG_NAMES, position=self.sim.leg_lengths.tolist()))
        # The platform where the simulated machine is (a real controller would publish its
        # forward kinematics), under the calibrator's base and platform joint frames.
        self.tf_pub.publish(transform_message(now.nanoseconds, [
            ('base', 'platform', *frame_of(pose_as_message(self.sim.pose)))]))

    def publish_truth(self):
        self.truth_pub.publish(PoseStamped(header=Header(stamp=self._settled, frame_id='base'),
                                           pose=pose_as_message(self.sim.pose)))

    def on_move(self, request, response):
        try:
            if request.mode == MoveHexapod.Request.POSE:
                legs = self.sim.move_pose(pose_from_message(request.pose))
            elif request.mode == MoveHexapod.Request.LEG_LENGTHS:
                legs = self.sim.move_legs(leg_lengths_from_message(request.leg_lengths))
            else:
                raise InvalidInputError(f'unknown move mode {request.mode}')
        except MachineAlignmentError as exc:
            self.get_logger().warning(f'move refused: {exc}')
            response.success, response.message = False, str(exc)
            return response
        self._settled = self.get_clock().now().to_msg()
        self.publish_truth()
        self.publish_legs()
        response.success, response.message = True, 'ok'
        response.leg_lengths = np.asarray(legs, float).tolist()
        response.settled = self._settled
        return response


def main(args=None):
    run_node(HexapodSimNode, args)


if __name__ == '__main__':
    main()
