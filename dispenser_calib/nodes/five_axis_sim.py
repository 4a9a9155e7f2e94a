"""five_axis_sim: the simulated five-axis dispenser (XYZAC, camera on Z) with true errors
of realistic size (``seed``), and its camera looking at the dot board on the table.

Service ``five_axis/move`` (MoveFiveAxis) drives the axes to a pose (refused outside a
stroke: nothing moves); ``five_axis/capture_board`` (CaptureDots) images the board at the
current pose and returns the dots found, with ``noise_px`` of detection noise and, with
probability ``bad_fraction``, one dot mis-detected and one occluded. A part lies on the
table: its CAD features ``part_cad`` (x y z per feature, m) placed at ``part_pose`` (x, y,
z m, rotation vector rad); ``five_axis/capture_features`` (CaptureDots: i the feature's
number) returns the features in view with the same noise. ``five_axis/capture_frame``
(CaptureFrame) returns the camera's frame of the board instead, rendered (perspective,
distortion, each dot drawn ``noise_px`` off, ``frame_noise`` grey levels; about 1 s a
frame); with probability
``bad_fraction`` one dot is hidden and another drawn 15-30 px off (dust).
The needle (its true tip ``needle_tip``, m in the camera frame) dispenses a test dot where
it touches the table (``five_axis/dispense``, std_srvs/Trigger);
``five_axis/capture_dispensed`` (CaptureDots: i the dot's number, in the order dispensed)
returns the dots in view with ``noise_px``.
With ``description`` (a machine description YAML, docs/machine_description.md) it is the
described dispenser: its camera, working distance and strokes, true errors of the built-in
kind about its nominal, its dots found to the described noise (``noise_px`` is then not
used) and its axes stopping as noisily as declared.
"""
import threading

import numpy as np
from alignment_msgs.srv import CaptureDots, CaptureFrame, MoveFiveAxis
from rclpy.node import Node
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from calib_core.errors import MachineAlignmentError
from calib_core.nodes.calibrator import READ_ONLY
from calib_core.nodes.images import image_as_message
from calib_core.nodes.qos import SERVICES
from calib_core.nodes.scene import TF_TOPIC, transform_message
from calib_core.nodes.spin import run_node
from dispenser_calib.core.localisation import reached
from dispenser_calib.core.model import nominal_frames
from dispenser_calib.core.description import read_description
from dispenser_calib.core.procedure import NEEDLE_TIP, PART_CAD, SHIPPED_WORKSPACE
from dispenser_calib.core.data import board_points
from dispenser_calib.sim.images import render_board
from dispenser_calib.sim.machine import (
    IMAGE_SIZE, PART_POSE, TRUE_TIP_OFFSET, observe, placed_part, points_in_view, true_model)


class FiveAxisSimNode(Node):

    def __init__(self):
        super().__init__('five_axis_sim')
        self.declare_parameter('seed', 0)
        self.declare_parameter('description', '', READ_ONLY)   # its camera and noise win
        self.declare_parameter('noise_px', 0.1)
        self.declare_parameter('bad_fraction', 0.0)
        self.declare_parameter('frame_noise', 2.0)
        self.declare_parameter('needle_tip', (NEEDLE_TIP + TRUE_TIP_OFFSET).tolist())  # 0.3, -0.2, 0.1 mm off
        self.declare_parameter('part_cad', PART_CAD.ravel().tolist())
        self.declare_parameter('part_pose', PART_POSE.tolist())  # 1.5, -1 mm, 0.03 rad
        g = lambda n: self.get_parameter(n).value  # noqa: E731
        cad = np.asarray(g('part_cad'), dtype=float)
        placed = np.asarray(g('part_pose'), dtype=float)
        if cad.size % 3 or not np.all(np.isfinite(cad)) or placed.shape != (6,):
            raise ValueError('part_cad must be x y z triples (m) and part_pose six values')
        self.features = placed_part(cad.reshape(-1, 3), placed)
        if g('noise_px') < 0 or not 0 <= g('bad_fraction') <= 1 or g('frame_noise') < 0:
            raise ValueError('noise_px and frame_noise must be >= 0 and bad_fraction in [0, 1]')
        self.frame_noise = float(g('frame_noise'))
        self.tip = np.asarray(g('needle_tip'), dtype=float)
        if self.tip.shape != (3,) or not np.all(np.isfinite(self.tip)):
            raise ValueError('needle_tip must be x, y, z (m) in the camera frame')
        self.dispensed = []
        self.seed, self.noise, self.bad = int(g('seed')), float(g('noise_px')), float(g('bad_fraction'))
        described = read_description(g('description')) if g('description') else None
        self.workspace = described.workspace() if described else SHIPPED_WORKSPACE
        self.image_size = described.image_size if described else IMAGE_SIZE
        self.pose_sigma = described.pose_sigma() if described else None
        self.frames = described.frames if described else nominal_frames
        if described:
            self.noise = described.centroid_sigma_px
        self.truth = true_model(self.seed, described.nominal() if described else None)
        self.pose = np.zeros(5)
        self.tf_pub = self.create_publisher(TFMessage, TF_TOPIC, 10)
        self.captures = 0
        self.rng = np.random.default_rng(self.seed + 90)
        self._lock = threading.Lock()
        self.create_service(MoveFiveAxis, 'five_axis/move', self.on_move, qos_profile=SERVICES)
        self.create_service(CaptureDots, 'five_axis/capture_board', self.on_capture,
                            qos_profile=SERVICES)
        self.create_service(CaptureDots, 'five_axis/capture_features', self.on_features,
                            qos_profile=SERVICES)
        self.create_service(CaptureFrame, 'five_axis/capture_frame', self.on_frame,
                            qos_profile=SERVICES)
        self.create_service(Trigger, 'five_axis/dispense', self.on_dispense, qos_profile=SERVICES)
        self.create_service(CaptureDots, 'five_axis/capture_dispensed', self.on_dispensed,
                            qos_profile=SERVICES)

    def on_move(self, request, response):
        try:
            pose = np.asarray(request.pose, dtype=float)
            if pose.shape != (5,) or not np.all(np.isfinite(pose)):
                raise MachineAlignmentError('a pose is five finite values: x, y, z (m), a, c (rad)')
            self.workspace.check(pose)
        except MachineAlignmentError as exc:
            self.get_logger().error(f'move refused: {exc}')
            response.success, response.message = False, str(exc)
            return response
        with self._lock:
            self.pose = pose
        # The machine's frames at this pose through its nominal kinematics (as its
        # controller would publish them).
        self.tf_pub.publish(transform_message(self.get_clock().now().nanoseconds,
                                              self.frames(pose)))
        response.success, response.message, response.pose = True, 'ok', [float(v) for v in pose]
        return response

    def on_capture(self, request, response):
        with self._lock:
            pose, self.captures = self.pose.copy(), self.captures + 1
            bad = 1.0 if self.rng.random() < self.bad else 0.0
            images, _ = observe(self.truth, pose[None], self.noise,
                                self.seed * 100003 + self.captures, bad,
                                image_size=self.image_size, workspace=self.workspace,
                                pose_sigma=self.pose_sigma)
        image = images[0]
        response.success, response.message = True, f'{len(image.indices)} dots'
        response.i = [int(v) for v in image.indices[:, 0]]
        response.j = [int(v) for v in image.indices[:, 1]]
        response.u = [float(v) for v in image.pixels[:, 0]]
        response.v = [float(v) for v in image.pixels[:, 1]]
        return response

    def on_frame(self, request, response):
        with self._lock:
            pose, self.captures = self.pose.copy(), self.captures + 1
            seed = self.seed * 100003 + self.captures
            bad = self.rng.random() < self.bad
            indices = board_points(self.workspace.board)[1]
            hidden, dust = self.rng.choice(len(indices), 2, replace=False)
            offset = self.rng.uniform(15, 30) * self.rng.choice([-1, 1], 2)
        occluded = (tuple(indices[hidden]),) if bad else ()
        displaced = {tuple(indices[dust]): offset} if bad else None
        frame = render_board(self.truth, pose, self.image_size, self.frame_noise, seed, occluded,
                             displaced, centre_noise_px=self.noise, workspace=self.workspace)
        response.success, response.message = True, 'ok'
        response.image = image_as_message(
            frame, Header(stamp=self.get_clock().now().to_msg(), frame_id='camera'))
        return response

    def on_dispense(self, request, response):
        with self._lock:
            self.dispensed.append(reached(self.truth, self.tip, self.pose[None])[0])
            count = len(self.dispensed)
        response.success, response.message = True, f'dot {count - 1} dispensed'
        return response

    def on_dispensed(self, request, response):
        with self._lock:
            dots = np.array(self.dispensed).reshape(-1, 3)
        return self._points_in_view(dots, response, 'dispensed dots')

    def on_features(self, request, response):
        return self._points_in_view(self.features, response, 'features')

    def _points_in_view(self, points, response, what):
        """The ``points`` (n, 3, board frame) in view at the current pose, numbered by
        their row, with ``noise_px``."""
        with self._lock:
            numbers, pixels = points_in_view(self.truth, points, self.pose.copy(), self.noise,
                                             self.rng, self.image_size)
        response.success, response.message = True, f'{len(numbers)} {what}'
        response.i, response.j = [int(k) for k in numbers], [0] * len(numbers)
        response.u = [float(v) for v in pixels[:, 0]]
        response.v = [float(v) for v in pixels[:, 1]]
        return response


def main(args=None):
    run_node(FiveAxisSimNode, args)


if __name__ == '__main__':
    main()
