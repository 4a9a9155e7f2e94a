"""The Jazzy main() block, shared by every node of the suite."""
import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor


def run_node(node_class, args=None, threads: int = 0) -> None:
    """Create ``node_class()``, spin it until Ctrl-C or shutdown, then clean up.

    ``threads`` > 0 spins a MultiThreadedExecutor, needed by nodes whose service callbacks
    wait for other callbacks (images, service responses)."""
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
