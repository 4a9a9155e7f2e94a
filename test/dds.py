"""Helpers for tests that run nodes as separate processes over DDS."""
from contextlib import contextmanager

import rclpy

from machine_alignment.launcher import Graph


def call(node, client, request, timeout=60.0):
    """Call a service from the test's client node and return the response."""
    assert client.wait_for_service(timeout_sec=30.0), f'{client.srv_name} not available'
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    assert future.done(), f'{client.srv_name} did not answer'
    return future.result()


@contextmanager
def running(spec, domain: str, out, client_name: str):
    """Start ``spec`` in ROS domain ``domain`` (logs in ``out/logs``) and a client node in
    the same domain; yields (graph, node)."""
    with Graph(spec, env={'ROS_DOMAIN_ID': domain}, log_dir=str(out / 'logs')) as graph:
        rclpy.init(domain_id=int(domain))
        node = rclpy.create_node(client_name)
        try:
            yield graph, node
        finally:
            node.destroy_node()
            rclpy.try_shutdown()


def machine_align(domain: str, *argv: str, timeout: float = 300.0):
    """Run ``machine-align ARGV`` as its own process on ROS domain ``domain``, as a user
    would from the venv; the finished process (returncode, stdout, stderr)."""
    import os
    import subprocess
    import sys
    return subprocess.run([sys.executable, '-m', 'machine_alignment.cli', *argv],
                          env={**os.environ, 'ROS_DOMAIN_ID': domain}, capture_output=True,
                          text=True, timeout=timeout)


@contextmanager
def node_in_process(node_class, monkeypatch, tmp_path, **parameters):
    """:func:`in_process_node` for a ``with`` block: the node is destroyed and rclpy shut
    down when the block ends."""
    node = in_process_node(node_class, monkeypatch, tmp_path, **parameters)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown()


def in_process_node(node_class, monkeypatch, tmp_path, **parameters):
    """``node_class()`` in this process with discovery off (nothing else sees it) and
    ``parameters`` (its output_dir and record_dir in ``tmp_path``); the caller destroys it
    and shuts rclpy down. A node that refuses to start has shut rclpy down already."""
    import rclpy
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF')     # read by rclpy.init
    arguments = ['--ros-args', '-p', f'output_dir:={tmp_path}', '-p', f'record_dir:={tmp_path}']
    for name, value in parameters.items():
        arguments += ['-p', f'{name}:={value}']
    rclpy.init(args=arguments)
    try:
        return node_class()
    except Exception:
        rclpy.shutdown()
        raise
