"""Parameters a node reads only at start-up are read-only (issue 54): a peer setting one at
run time is refused, instead of the node reporting the new value and going on with the
old one."""
import os

DOMAIN = str(210 + os.getpid() % 20)   # each DDS test module has its own band
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

import rclpy  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402

from dds import running  # noqa: E402
from machine_alignment.launcher import NodeSpec  # noqa: E402


def _set(node, target: str, name: str, value: float) -> bool:
    setter = node.create_client(SetParameters, f'/{target}/set_parameters')
    assert setter.wait_for_service(timeout_sec=20.0)
    future = setter.call_async(SetParameters.Request(parameters=[Parameter(
        name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                        double_value=value))]))
    rclpy.spin_until_future_complete(node, future, timeout_sec=10.0)
    return future.result().results[0].successful


def test_start_up_parameters_are_refused_at_run_time(tmp_path):
    spec = [NodeSpec('hexapod_calib.nodes.pose_sensor_sim', {'position_noise': 1e-6})]
    with running(spec, DOMAIN, tmp_path, 'read_only_probe') as (_, node):
        assert not _set(node, 'pose_sensor_sim', 'position_noise', 1.0)
        assert not _set(node, 'pose_sensor_sim', 'angle_noise', 1.0)
        # one it reads at every call may change
        assert _set(node, 'pose_sensor_sim', 'wait_timeout_s', 3.0)
