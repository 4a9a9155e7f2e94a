"""gantry_sim: the simulated XY camera gantry.

Publishes the encoder reading on ``gantry/state``, the machine's temperature on
``/machine/temperature`` (sensor_msgs/Temperature, degrees Celsius) and, for the camera
simulator only, the true camera position on ``sim/truth/camera_position``. Service
``gantry/move`` moves to an absolute axis position (m) and refuses targets outside the
travel. Its temperature changes as it runs (a warm-up and the shop's cycle: see
MachineTemperature), and its screws grow by ``screw_expansion`` (1/K), which the encoders
do not see. Each move lands within ``landing_sigma`` (m, 1 sigma per axis; by default
0.25 um, the 1/50 px the source cites for its Mark centres at its 12.5 um pixels, so the
camera-measured positions scatter as the source's did), drawn from ``seed``.
"""
import dataclasses
import threading

from alignment_msgs.msg import GantryState
from alignment_msgs.srv import MoveGantry
from geometry_msgs.msg import PointStamped
from rclpy.node import Node
from sensor_msgs.msg import Temperature
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from calib_core.errors import MachineAlignmentError
from calib_core.frames import planar
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.scene import TF_TOPIC, transform_message
from calib_core.nodes.spin import run_node
from calib_core.schema import CELSIUS_ZERO_K
from calib_core.temperature import TEMPERATURE_TOPIC
from printer_alignment.nodes.conversions import gantry_state_as_message
from printer_alignment.sim.gantry import GantryErrors, GantrySim, MachineTemperature, Travel


class GantrySimNode(Node):

    def __init__(self):
        super().__init__('gantry_sim')
        self.declare_parameter('x_min', 0.0)
        self.declare_parameter('x_max', 0.200)
        self.declare_parameter('y_min', 0.0)
        self.declare_parameter('y_max', 0.150)
        self.declare_parameter('ideal', False)
        self.declare_parameter('state_rate_hz', 10.0)
        self.declare_parameter('start_temperature', 293.15)   # K
        self.declare_parameter('warm_up', 0.0)                # K to the running equilibrium
        self.declare_parameter('warm_up_time', 3600.0)        # s, its time constant
        self.declare_parameter('cycle_amplitude', 0.0)        # K, the shop's cycle
        self.declare_parameter('cycle_period', 1800.0)        # s
        self.declare_parameter('screw_expansion', 0.0)        # 1/K, unseen by the encoders
        self.declare_parameter('landing_sigma', 0.25e-6)      # m, 1 sigma: 1/50 px of 12.5 um
        self.declare_parameter('seed', 0)                     # of the landing scatter
        p = {n: self.get_parameter(n).value for n in ('x_min', 'x_max', 'y_min', 'y_max')}
        if not (p['x_min'] < p['x_max'] and p['y_min'] < p['y_max']):
            raise ValueError(f'invalid travel {p}')
        rate = self.get_parameter('state_rate_hz').value
        if not rate > 0:
            raise ValueError('state_rate_hz must be positive')
        self.temperature = MachineTemperature(*(
            float(self.get_parameter(n).value) for n in (
                'start_temperature', 'warm_up', 'warm_up_time', 'cycle_amplitude',
                'cycle_period')))
        expansion = float(self.get_parameter('screw_expansion').value)
        if not abs(expansion) < 1e-3:
            raise ValueError(f'|screw_expansion| must be below 1e-3 1/K, not {expansion}')
        errors = GantryErrors.ideal() if self.get_parameter('ideal').value else GantryErrors()
        errors = dataclasses.replace(errors, screw_expansion=expansion)
        self.gantry = GantrySim(errors, Travel(**p),
                                float(self.get_parameter('landing_sigma').value),
                                int(self.get_parameter('seed').value))
        self._started = self.get_clock().now()
        self._lock = threading.Lock()
        self.state_pub = self.create_publisher(GantryState, 'gantry/state', 10)
        self.truth_pub = self.create_publisher(PointStamped, 'sim/truth/camera_position', LATCHED)
        self.temperature_pub = self.create_publisher(Temperature, TEMPERATURE_TOPIC, 10)
        self.tf_pub = self.create_publisher(TFMessage, TF_TOPIC, 10)
        self.create_service(MoveGantry, 'gantry/move', self.on_move, qos_profile=SERVICES)
        self.create_timer(1.0 / rate, self.publish_state)
        self.publish_state()

    def publish_state(self):
        with self._lock:
            now = self.get_clock().now()
            header = Header(stamp=now.to_msg(), frame_id='gantry')
            # The machine's temperature changes as it runs; moves are instantaneous.
            kelvin = self.temperature.at(max((now - self._started).nanoseconds, 0) * 1e-9)
            self.gantry.warming = kelvin - self.temperature.start
            self.state_pub.publish(gantry_state_as_message(
                self.gantry.axis_position, self.gantry.revs, header))
            # The carriage where the drive reads it (REP 105's moving frame under the
            # calibrated plate -> gantry of the vision calibrator's /tf_static).
            self.tf_pub.publish(transform_message(now.nanoseconds, [
                ('gantry', 'carriage', *planar(*self.gantry.axis_position, 0.0))]))
            truth = self.gantry.true_camera_position()
        point = PointStamped(header=header)
        point.point.x, point.point.y = float(truth[0]), float(truth[1])
        self.truth_pub.publish(point)
        self.temperature_pub.publish(Temperature(header=header,
                                                 temperature=kelvin - CELSIUS_ZERO_K))

    def on_move(self, request, response):
        try:
            with self._lock:
                reached = self.gantry.move(request.x, request.y)
            response.success, response.message = True, 'ok'
            response.x, response.y = float(reached[0]), float(reached[1])
        except MachineAlignmentError as exc:
            self.get_logger().warning(str(exc))
            response.success, response.message = False, str(exc)
            response.x, response.y = map(float, self.gantry.axis_position)
        self.publish_state()
        return response


def main(args=None):
    run_node(GantrySimNode, args)


if __name__ == '__main__':
    main()
