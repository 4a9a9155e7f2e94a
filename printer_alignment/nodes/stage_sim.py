"""stage_sim: the simulated XY-Theta alignment stage (3-PRP).

Service ``stage/move`` (MoveStage) moves the three chains to absolute inputs (m) and
refuses inputs outside the stroke ([-5, 5] mm) without moving. ``description``: a stage
description YAML: the user's stage (its guides, Marks and stroke, its chains landing as
declared) with the shipped stage's errors, mounted under the camera gantry as the shipped
one is (:func:`printer_alignment.sim.stage.described_truth`; '': the shipped stage). Publishes the encoders on
``stage/state`` and, for the camera simulator only, the platform's true plate pose on
``sim/truth/stage_pose`` (latched).
"""
import threading

import numpy as np
from alignment_msgs.msg import StagePose, StageState
from alignment_msgs.srv import MoveStage
from rclpy.node import Node
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from calib_core.errors import MachineAlignmentError
from calib_core.frames import planar
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.scene import TF_TOPIC, transform_message
from calib_core.nodes.spin import run_node
from calib_core.nodes.calibrator import set_described_parameters
from printer_alignment.core.stage import LANDING_SIGMA, NOMINAL_STAGE
from printer_alignment.core.stage_description import read_description
from printer_alignment.sim.stage import TRUE_STAGE, StageSim, described_truth

# What a description sets (and the launch may not set beside it).
DESCRIBED_DEFAULTS = {'landing_sigma': LANDING_SIGMA}


class StageSimNode(Node):

    def __init__(self):
        super().__init__('stage_sim')
        self.declare_parameter('landing_sigma', 1.2e-6)
        self.declare_parameter('ideal', False)
        self.declare_parameter('seed', 0)
        self.declare_parameter('state_rate_hz', 10.0)
        self.declare_parameter('description', '')   # '': the shipped stage
        ideal = bool(self.get_parameter('ideal').value)
        described = None
        if self.get_parameter('description').value:
            described = read_description(self.get_parameter('description').value)
            set_described_parameters(self, {'landing_sigma': described.landing_sigma()},
                                     DESCRIBED_DEFAULTS)
        landing = float(self.get_parameter('landing_sigma').value)
        rate = float(self.get_parameter('state_rate_hz').value)
        if not (landing >= 0 and rate > 0):
            raise ValueError('landing_sigma must be >= 0 and state_rate_hz > 0')
        seed = int(self.get_parameter('seed').value)
        if described is None:
            self.stage = StageSim(NOMINAL_STAGE if ideal else TRUE_STAGE, landing, seed=seed)
        else:
            self.stage = StageSim(described_truth(described, ideal), landing, seed=seed,
                                  stroke=described.stroke, marks=described.marks)
        self._lock = threading.Lock()
        self.state_pub = self.create_publisher(StageState, 'stage/state', 10)
        self.truth_pub = self.create_publisher(StagePose, 'sim/truth/stage_pose', LATCHED)
        self.tf_pub = self.create_publisher(TFMessage, TF_TOPIC, 10)
        self.create_service(MoveStage, 'stage/move', self.on_move, qos_profile=SERVICES)
        self.create_timer(1.0 / rate, self.publish_state)
        self.publish_state()

    def _header(self):
        return Header(stamp=self.get_clock().now().to_msg(), frame_id='stage')

    def publish_state(self):
        with self._lock:
            header = self._header()
            q, directions = self.stage.q.tolist(), self.stage.directions.astype(int).tolist()
            pose = self.stage.true_pose()
        self.state_pub.publish(StageState(header=header, q=q, direction=directions))
        self.truth_pub.publish(StagePose(header=Header(stamp=header.stamp, frame_id='plate'),
                                         x=float(pose[0]), y=float(pose[1]),
                                         theta=float(pose[2])))
        # The stage's platform where the simulated stage put it (the plate frame).
        self.tf_pub.publish(transform_message(
            header.stamp.sec * 10**9 + header.stamp.nanosec,
            [('plate', 'stage_platform', *planar(*pose))]))

    def on_move(self, request, response):
        try:
            if len(request.q) != 3:
                raise MachineAlignmentError(f'stage/move needs 3 chain inputs, got {len(request.q)}')
            with self._lock:
                self.stage.move(np.asarray(request.q, dtype=float))
            response.success, response.message = True, 'ok'
        except MachineAlignmentError as exc:
            self.get_logger().warning(str(exc))
            response.success, response.message = False, str(exc)
        with self._lock:
            response.q = self.stage.q.tolist()
            response.direction = self.stage.directions.astype(int).tolist()
        self.publish_state()
        return response


def main(args=None):
    run_node(StageSimNode, args)


if __name__ == '__main__':
    main()
