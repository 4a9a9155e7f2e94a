"""The printer's vision chain on three "computers" (issue 19): network namespaces joined by
a bridge, as a production line runs them on a camera PC, a motion controller and a
metrology PC. Discovery (multicast, ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET) and the data
between namespaces go over that link: each namespace has its own loopback, and Fast DDS's
shared memory does not reach across namespaces (measured: a SHM-only subscriber in
another namespace receives nothing, in the same namespace it does), so only the camera
and the detector, on one "computer", may use it, as they would on a camera PC. Nothing is
shared through files, and the calibration completes. Skipped, with the reason, where
namespaces cannot be made."""
import json
import os
import shutil
import subprocess
import sys
import uuid

import pytest

from machine_alignment.launcher import Graph, printer_graph

HOSTS = {'printer_alignment.nodes.gantry_sim': 'motion',
         'printer_alignment.nodes.camera_sim': 'camera',
         'printer_alignment.nodes.mark_detector': 'camera',
         'printer_alignment.nodes.vision_calibrator': 'metrology'}
CLIENT = '''
import json, rclpy
from alignment_msgs.srv import RunCalibration
rclpy.init()
node = rclpy.create_node('line_operator')
client = node.create_client(RunCalibration, 'vision_calibrator/calibrate')
ok = client.wait_for_service(timeout_sec=60.0)
result = None
if ok:
    future = client.call_async(RunCalibration.Request(plan_yaml='{nx: 3, ny: 2}'))
    rclpy.spin_until_future_complete(node, future, timeout_sec=240.0)
    result = future.result()
print(json.dumps({'service': ok, 'success': bool(result and result.success),
                  'message': result.message if result else 'no answer',
                  'values': dict(zip(result.result.names, result.result.values)) if result else {}}))
'''


def _sh(*args):
    return subprocess.run(args, capture_output=True, text=True, timeout=30)


@pytest.fixture
def hosts():
    """Three namespaces on one bridge, 10.231.0.1-3/24; yields ``{host: namespace}``."""
    if os.geteuid() != 0 or not shutil.which('ip'):
        pytest.skip('network namespaces need root and iproute2 (ip)')
    tag = uuid.uuid4().hex[:6]
    bridge, names = f'mab{tag}', {h: f'ma_{h}_{tag}' for h in ('motion', 'camera', 'metrology')}
    if _sh('ip', 'link', 'add', bridge, 'type', 'bridge').returncode != 0:
        pytest.skip('cannot create a network bridge here (no CAP_NET_ADMIN?)')
    try:
        _sh('ip', 'link', 'set', bridge, 'up')
        for k, (host, ns) in enumerate(names.items(), start=1):
            inner, outer = f'mai{tag}{k}', f'mao{tag}{k}'
            steps = [('ip', 'netns', 'add', ns),
                     ('ip', 'link', 'add', inner, 'type', 'veth', 'peer', 'name', outer),
                     ('ip', 'link', 'set', inner, 'netns', ns),
                     ('ip', 'link', 'set', outer, 'master', bridge),
                     ('ip', 'link', 'set', outer, 'up'),
                     ('ip', 'netns', 'exec', ns, 'ip', 'addr', 'add', f'10.231.0.{k}/24', 'dev', inner),
                     ('ip', 'netns', 'exec', ns, 'ip', 'link', 'set', inner, 'up'),
                     ('ip', 'netns', 'exec', ns, 'ip', 'link', 'set', 'lo', 'up')]
            for step in steps:
                done = _sh(*step)
                if done.returncode != 0:
                    pytest.skip(f'cannot set up network namespaces: {" ".join(step)}: '
                                f'{done.stderr.strip()}')
        yield names
    finally:
        for ns in names.values():
            _sh('ip', 'netns', 'del', ns)
        _sh('ip', 'link', 'del', bridge)


def test_vision_calibration_with_nodes_on_three_hosts(hosts, tmp_path):
    env = {'ROS_DOMAIN_ID': '42', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
           'PYTHONPATH': os.pathsep.join(sys.path)}
    spec = printer_graph(output_dir=str(tmp_path / 'metrology' / 'calibration'),
                         record_dir=str(tmp_path / 'metrology' / 'runs'))
    with Graph(spec, env=env, log_dir=str(tmp_path / 'logs'),
               prefix=lambda node: ['ip', 'netns', 'exec', hosts[HOSTS[node.module]]]) as graph:
        client = subprocess.run(['ip', 'netns', 'exec', hosts['metrology'], sys.executable,
                                 '-c', CLIENT], capture_output=True, text=True, timeout=300,
                                env={**os.environ, **env})
        assert all(graph.alive()), 'a node died; see the logs'
    answer = json.loads(client.stdout.strip().splitlines()[-1])
    assert answer['service'], 'the calibrator was not discovered across the link'
    assert answer['success'], answer['message']
    assert abs(answer['values']['lead_x'] - 0.0159972) < 2e-6
    assert (tmp_path / 'metrology' / 'calibration' / 'vision.v1.yaml').exists()
