"""QoS profiles shared by the suite's nodes."""
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

# Results and truth: reliable, and kept for subscribers that join later (depth 1).
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
