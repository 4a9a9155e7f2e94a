"""QoS profiles shared by the suite's nodes."""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Results and truth: reliable, and kept for subscribers that join later (depth 1).
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)

# Services: every request of a burst kept until served (the default keeps the last 10:
# of 50 calls at once from one client, 11 were answered and the rest waited out their
# callers' timeouts).
SERVICES = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
