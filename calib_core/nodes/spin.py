"""The Jazzy main() block, shared by every node of the suite."""
import sys

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor


def run_node(node_class, args=None, threads: int = 0) -> None:
    """Create ``node_class()``, spin it until Ctrl-C or shutdown, then clean up.

    ``threads`` > 0 spins a MultiThreadedExecutor, needed by nodes whose service callbacks
    wait for other callbacks (images, service responses)."""
    sys.unraisablehook = quiet_half_built_futures
    rclpy.init(args=args)
    node = None
    try:
        node = node_class()
        if threads:
            executor = MultiThreadedExecutor(num_threads=threads)
            executor.add_node(node)
            executor.spin()
        else:
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:
        # A SIGINT or SIGTERM that shuts the context down while the executor builds its
        # next wait set surfaces as this instead of ExternalShutdownException: the same
        # ordered stop, not a failure. With the context still valid it is one.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def quiet_half_built_futures(unraisable) -> None:
    """sys.unraisablehook that drops one known rclpy race and passes on the rest: a SIGINT
    that lands while the executor builds a Task, before Future.__init__ set its fields,
    leaves a half-built object whose Future.__del__ then raises AttributeError ('Task'
    object has no attribute '_exception'), printed as a traceback on a node's ordered stop
    (seen once in the launcher's test of killed nodes). Nothing is lost: the object never
    held a result."""
    if (isinstance(unraisable.exc_value, AttributeError)
            and getattr(unraisable.object, '__qualname__', '') == 'Future.__del__'):
        return
    sys.__unraisablehook__(unraisable)
