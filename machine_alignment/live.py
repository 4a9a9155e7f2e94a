"""Calling the suite's services on a running graph from plain Python (the venv has no
``ros2`` command): one client node in its own rclpy context, progress messages handed to
a callback while the call runs. Used by ``machine-align call`` and the demo."""
from __future__ import annotations

import os
import signal
import threading
import time
from typing import Callable

import rclpy
from alignment_msgs.msg import Progress
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from calib_core.errors import CalibrationError
from calib_core.nodes.qos import SERVICES


class LiveClient:
    """A client node on ROS domain ``domain`` (default: ``ROS_DOMAIN_ID``, else 0), in a
    context of its own so it can live beside other rclpy users in one process. Discovery
    defaults to localhost, as the launcher's graphs use."""

    WATCH_PERIOD = 1.0   # s between checks that the server is still in the graph
    PROGRESS_DRAIN = 0.2   # s for progress sent before the answer to arrive after it

    def __init__(self, name: str = 'machine_align_client', domain: int | None = None):
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        if domain is None:
            domain = int(os.environ.get('ROS_DOMAIN_ID', '0') or 0)
        self.context = rclpy.Context()
        # No rclpy signal handler: it would shut the context down on Ctrl-C, and the call
        # needs it to ask the node to cancel (Python's KeyboardInterrupt comes as usual).
        rclpy.init(context=self.context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def __enter__(self) -> 'LiveClient':
        return self

    def __exit__(self, *exc) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def call(self, service_type, service: str, request, progress_topic: str | None = None,
             on_progress: Callable | None = None, timeout: float = 600.0,
             wait: float = 30.0, cancel: str | None = None):
        """The response of ``service`` to ``request``; ``on_progress(step, total, message)``
        for every Progress message on ``progress_topic`` meanwhile.

        The server is watched while the call runs: a node that is stopped leaves the graph
        at once, one that is killed when DDS's liveliness lease runs out (20 s with Fast
        DDS's default), and the call then ends instead of waiting out ``timeout``.

        Ctrl-C while it runs calls ``cancel`` (the node's std_srvs/Trigger cancel, where
        given) and goes on waiting for the answer, which then says the run was cancelled; a
        second Ctrl-C stops waiting.

        Raises
        ------
        CalibrationError
            The service does not come up within ``wait`` s, goes away before answering, or
            does not answer within ``timeout`` s."""
        subscription = None
        if progress_topic and on_progress:
            subscription = self.node.create_subscription(
                Progress, progress_topic,
                lambda msg: on_progress(msg.step, msg.total, msg.message), 10)
        client = self.node.create_client(service_type, service, qos_profile=SERVICES)
        # Ctrl-C is noted here and acted on between waits: raised inside rclpy's wait (C++),
        # a KeyboardInterrupt came out as a pybind11 RuntimeError now and then.
        interrupts = []
        previous = (signal.signal(signal.SIGINT, lambda *_: interrupts.append(True))
                    if threading.current_thread() is threading.main_thread() else None)
        try:
            if not client.wait_for_service(timeout_sec=wait):
                raise CalibrationError(f'service {service} is not available (is its graph '
                                       f'running on ROS domain {self.context.get_domain_id()}?)')
            if interrupts:
                raise KeyboardInterrupt
            future = client.call_async(request)
            start = time.monotonic()
            missed, cancelled = 0, False
            while not future.done():
                left = timeout - (time.monotonic() - start)
                if left <= 0:
                    raise CalibrationError(f'{service} did not answer within {timeout:g} s')
                self.executor.spin_until_future_complete(
                    future, timeout_sec=min(self.WATCH_PERIOD, left))
                if interrupts and not future.done():
                    if cancel is None or len(interrupts) > 1:
                        raise KeyboardInterrupt   # no cancel, or a second Ctrl-C
                    if not cancelled:
                        self._cancel(cancel)
                        cancelled = True
                # Two misses in a row: one can be a discovery update in flight.
                missed = 0 if future.done() or client.service_is_ready() else missed + 1
                if missed >= 2:
                    raise CalibrationError(
                        f'{service} went away {time.monotonic() - start:.0f} s into the call '
                        'without answering: its node died or was stopped (see the launcher\'s '
                        'output or the node\'s log); nothing was received from it')
            if subscription is not None:
                # The node sends its last progress before it answers, but on another
                # reader: the answer can be taken first, and the last line ("7/7") was
                # lost now and then. What has come meanwhile is delivered before the
                # subscription goes.
                drained = time.monotonic() + self.PROGRESS_DRAIN
                while time.monotonic() < drained:
                    self.executor.spin_once(timeout_sec=self.PROGRESS_DRAIN / 4)
            return future.result()
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
            self.node.destroy_client(client)
            if subscription is not None:
                self.node.destroy_subscription(subscription)

    def _cancel(self, service: str) -> None:
        """Ask ``service`` (a std_srvs/Trigger cancel) to stop the run, and say what it
        answered."""
        from std_srvs.srv import Trigger
        client = self.node.create_client(Trigger, service)
        try:
            answer = None
            if client.wait_for_service(timeout_sec=5.0):
                future = client.call_async(Trigger.Request())
                self.executor.spin_until_future_complete(future, timeout_sec=10.0)
                answer = future.result()
            print(f'cancel: {answer.message if answer else f"{service} did not answer"}; '
                  'waiting for the run to stop (Ctrl-C again to stop waiting)', flush=True)
        finally:
            self.node.destroy_client(client)
