"""camera_sim: the simulated 640x480 gantry camera.

Renders what the camera sees of the scene (dot plate, substrate or stencil Marks) at the
gantry's true position, read from ``sim/truth/camera_position`` (simulators may use truth;
calibration nodes never do). Publishes ``camera/image_raw`` (mono8, sensor-data QoS) and
``camera/camera_info``.

Scene ``stage``: the printer with its XY-Theta stage. The platform's Marks move with
``sim/truth/stage_pose``; the camera is two-way, and service ``camera/select_view``
(SelectView) switches between the ``substrate`` (down) and the ``stencil`` (up). Parameters
``substrate_shift`` (x m, y m, rad: how the substrate is fixed on the platform) and
``stencil_marks`` (plate x, y of each stencil fiducial, m; empty: the default stencil);
``stage_description``: a stage description YAML (the user's stage as ``stage_sim`` builds
it from the same file: its calibration Marks, the substrate beside them; '': the shipped
stage).

Scene ``grid_plate``: a (2 ``grid_half`` + 1)-square plate of ``grid_pitch`` (m) with 1 um
RMS mark errors, placed as the grid calibration asks on ``/grid_calibrator/placement``:
the simulated operator puts its centre mark under the camera (turned 90 degrees
counter-clockwise for ``rotated``, one pitch along +x for ``shifted``) to within 50 um and
100 urad, squared to the stage's X axis at ``plate_square_to`` (rad, in the scene's frame;
a real operator squares the plate by jogging X under the camera), then confirms with
``grid_calibrator/confirm_placement``.
"""
import threading

import numpy as np
from alignment_msgs.msg import GridPlacement, StagePose
from alignment_msgs.srv import SelectView
from geometry_msgs.msg import PointStamped
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.time import Time
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from calib_core.nodes.images import image_as_message
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.spin import run_node
from printer_alignment.core.geometry import CameraToPlate
from printer_alignment.sim.camera import CameraOptics, CameraSim
from printer_alignment.core.stage_description import read_description as read_stage_description
from printer_alignment.sim.scene import PlacedPlate, StageScene
from printer_alignment.sim.scenes import grid_plate, make_scene, stage_scene

PLACEMENT_TOPIC = '/grid_calibrator/placement'      # the grid calibrator's request


class CameraSimNode(Node):

    def __init__(self):
        super().__init__('camera_sim')
        self.declare_parameter('scene', 'dot_plate')
        self.declare_parameter('rate_hz', 4.0)
        self.declare_parameter('seed', 0)
        self.declare_parameter('pixel_size', 12.3369e-6)
        self.declare_parameter('angle', float(np.deg2rad(0.35)))
        self.declare_parameter('blur_sigma', 0.8)
        self.declare_parameter('read_noise', 1.5)
        self.declare_parameter('k1', 0.0)
        self.declare_parameter('gradient_x', 0.0)
        self.declare_parameter('substrate_shift', [0.0, 0.0, 0.0])
        self.declare_parameter('stencil_marks', [0.0])
        self.declare_parameter('stage_description', '')   # '': the shipped stage
        self.declare_parameter('grid_half', 4)
        self.declare_parameter('grid_pitch', 7.5e-3)
        self.declare_parameter('plate_square_to', 0.0)
        g = self.get_parameter
        self.square_to = float(g('plate_square_to').value)
        if not np.isfinite(self.square_to):
            raise ValueError('plate_square_to must be a finite angle (rad)')
        rate = g('rate_hz').value
        if not rate > 0 or not g('pixel_size').value > 0 or g('blur_sigma').value < 0:
            raise ValueError('rate_hz and pixel_size must be positive, blur_sigma >= 0')
        optics = CameraOptics(
            camera2plate=CameraToPlate(g('pixel_size').value, g('angle').value),
            distortion=(g('k1').value, 0.0, 0.0, 0.0), blur_sigma=g('blur_sigma').value,
            read_noise=g('read_noise').value, gradient=(g('gradient_x').value, 0.0))
        scene = make_scene(g('scene').value)
        if isinstance(scene, StageScene):
            scene = self._stage_scene(g('substrate_shift').value, g('stencil_marks').value,
                                      g('stage_description').value)
        self.seed = int(g('seed').value)
        if isinstance(scene, PlacedPlate):
            if not (g('grid_half').value >= 1 and 0 < g('grid_pitch').value < 0.05):
                raise ValueError('grid_half must be >= 1 and grid_pitch a length in m')
            scene = grid_plate(g('grid_half').value, g('grid_pitch').value, seed=self.seed)
        self.camera = CameraSim(scene, optics, seed=self.seed)
        self._position = None
        self._pending = None          # a grid placement asked for, not yet made
        self._stamps = {}      # truth source -> stamp of its latest state
        self._rendered = (None, None)      # the last frame's state and its pixels
        self._lock = threading.Lock()
        self.image_pub = self.create_publisher(Image, 'camera/image_raw', qos_profile_sensor_data)
        self.info_pub = self.create_publisher(CameraInfo, 'camera/camera_info', qos_profile_sensor_data)
        self.create_subscription(PointStamped, 'sim/truth/camera_position', self.on_truth, LATCHED)
        if isinstance(scene, StageScene):
            self.create_subscription(StagePose, 'sim/truth/stage_pose', self.on_stage, LATCHED)
            self.create_service(SelectView, 'camera/select_view', self.on_select_view,
                                qos_profile=SERVICES)
        if isinstance(scene, PlacedPlate):
            self.create_subscription(GridPlacement, PLACEMENT_TOPIC, self.on_placement, LATCHED)
            self.confirm_client = self.create_client(Trigger, 'grid_calibrator/confirm_placement')
        self.create_timer(1.0 / rate, self.capture)

    @staticmethod
    def _stage_scene(shift, stencil, description: str) -> StageScene:
        shift = [float(v) for v in shift]
        stencil = [float(v) for v in stencil]
        if len(shift) != 3 or not np.all(np.isfinite(shift)):
            raise ValueError('substrate_shift must be three finite numbers (x m, y m, rad)')
        described = read_stage_description(description) if description else None
        if len(stencil) <= 1:
            return stage_scene(shift, description=described)
        if len(stencil) % 2 or not np.all(np.isfinite(stencil)):
            raise ValueError('stencil_marks must be finite x, y pairs (m)')
        return stage_scene(shift, np.reshape(stencil, (-1, 2)), described)

    def _frame_stamp(self):
        """The time at which everything a frame shows is known to be true: the oldest of
        the truth sources' latest stamps. The newest would let a fresh stage update stamp
        a frame that still shows the gantry before its last move (lock held)."""
        if 'gantry' not in self._stamps:
            return None
        return min(self._stamps.values()).to_msg()

    def on_truth(self, msg):
        with self._lock:
            self._position = np.array([msg.point.x, msg.point.y])
            self._stamps['gantry'] = Time.from_msg(msg.header.stamp)
        self._place_pending()

    def on_stage(self, msg):
        with self._lock:
            self.camera.scene.pose = np.array([msg.x, msg.y, msg.theta])
            self._stamps['stage'] = Time.from_msg(msg.header.stamp)

    def on_select_view(self, request, response):
        if request.view not in ('substrate', 'stencil'):
            response.success = False
            response.message = f'unknown view {request.view!r}; use substrate or stencil'
            return response
        with self._lock:
            # Frames rendered from now on show the new view; the detector only takes
            # frames stamped after its request, and the truth sources refresh at 10 Hz.
            self.camera.scene.view = request.view
        response.success, response.message = True, 'ok'
        return response

    def on_placement(self, msg):
        """Place the plate as asked, as an operator would, once the camera's position
        after the request is known (the request may arrive before the gantry's truth)."""
        with self._lock:
            self._pending = msg
        self._place_pending()

    def _place_pending(self):
        """The pending placement, if the gantry's truth is newer than its request: centre
        mark under the camera, off by up to 50 um and 100 urad (seeded per region and
        placement), then confirm."""
        with self._lock:
            msg = self._pending
            seen = self._stamps.get('gantry')
            if msg is None or self._position is None or seen is None or \
                    seen < Time.from_msg(msg.header.stamp):
                return
            self._pending = None
        rng = np.random.default_rng([self.seed, int(msg.region), len(msg.placement),
                                     ord(msg.placement[:1] or ' ')])
        shift = np.array([msg.pitch, 0.0]) if msg.placement == 'shifted' else np.zeros(2)
        turn = np.pi / 2 if msg.placement == 'rotated' else 0.0
        with self._lock:
            x, y = self._position + shift + rng.uniform(-50e-6, 50e-6, 2)
            self.camera.scene.place(x, y, turn + self.square_to + rng.uniform(-100e-6, 100e-6))
        self.get_logger().info(f'grid plate placed: region {msg.region}, {msg.placement}')
        self.confirm_client.call_async(Trigger.Request())

    def _frame_state(self, position) -> tuple:
        """What a frame shows: gantry position, stage pose and view, the plate's pose, to
        1 nm / 1 nrad (lock held). The frame's noise is drawn from it rather than from how
        many frames the free-running timer rendered before: every frame of one state is
        the same image, so a run of the graph gives the same numbers however its
        processes are scheduled, and a state already rendered need not be again."""
        state = list(np.round(np.asarray(position) * 1e9).astype(np.int64))
        scene = self.camera.scene
        if isinstance(scene, StageScene):
            state += list(np.round(np.asarray(scene.pose) * 1e9).astype(np.int64))
            state.append(0 if scene.view == 'substrate' else 1)
        if isinstance(scene, PlacedPlate):
            state += list(np.round(np.asarray(scene.pose) * 1e9).astype(np.int64))
        return tuple(int(v) & 0xFFFFFFFFFFFF for v in state)

    def capture(self):
        with self._lock:
            position = self._position
            stamp = self._frame_stamp()
            state = None if position is None else self._frame_state(position)
        if position is None:
            return  # no gantry yet: a real camera would see nothing useful either
        # Stamped with the time the rendered position was true, not with the capture time:
        # a truth update still queued behind a long render would otherwise give a frame of
        # the old position with a new stamp, which a detector waiting for a frame newer than
        # the move accepts (a few um of error after a 1 mm pre-positioning move).
        header = Header(stamp=stamp, frame_id='camera')
        if self._rendered[0] != state:
            # A machine at rest shows the same frame: rendering it again (20-40 ms) would
            # only spend the CPU the rest of the graph runs on.
            noise = np.random.default_rng([self.seed, *state])
            self._rendered = (state, self.camera.capture(position, noise))
        pixels = self._rendered[1]
        self.image_pub.publish(image_as_message(pixels, header))
        o = self.camera.optics
        info = CameraInfo(header=header, height=o.height, width=o.width,
                          distortion_model='plumb_bob')
        info.d = [float(x) for x in o.distortion] + [0.0]
        info.k = o.camera_matrix().ravel().tolist()
        info.p = np.hstack([o.camera_matrix(), np.zeros((3, 1))]).ravel().tolist()
        info.r = np.eye(3).ravel().tolist()
        self.info_pub.publish(info)


def main(args=None):
    run_node(CameraSimNode, args)


if __name__ == '__main__':
    main()
