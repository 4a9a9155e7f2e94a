"""The Jazzy main() block, shared by every node of the suite."""
import rclpy
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
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
