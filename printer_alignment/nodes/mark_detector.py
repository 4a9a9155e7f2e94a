"""mark_detector: sub-pixel Mark centres from camera images.

Subscribes ``camera/image_raw``; publishes every detection on ``marks`` (MarkArray with
``status`` "ok" or the reason it failed). Service ``mark_detector/detect`` (DetectMarks)
detects in the next image taken after the request, with the request's shape and count.
"""
import threading

from alignment_msgs.msg import MarkArray
from alignment_msgs.srv import DetectMarks
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.time import Time
from sensor_msgs.msg import Image

from calib_core.errors import MachineAlignmentError
from calib_core.marks import SHAPES, DetectorConfig, detect_marks
from calib_core.nodes.qos import SERVICES
from calib_core.nodes.images import image_from_message
from calib_core.nodes.spin import run_node
from printer_alignment.nodes.conversions import marks_as_message

LATEST_IMAGE = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                          reliability=ReliabilityPolicy.BEST_EFFORT)


class MarkDetectorNode(Node):

    def __init__(self):
        super().__init__('mark_detector')
        self.declare_parameter('shape', '')
        self.declare_parameter('expected_count', 0)
        self.declare_parameter('min_snr', 6.0)
        self.declare_parameter('polarity', 'auto')
        self.declare_parameter('min_size_px', 2.5)
        self.declare_parameter('max_size_px', 120.0)
        self.declare_parameter('continuous', True)
        self.declare_parameter('service_timeout_s', 5.0)
        g = lambda n: self.get_parameter(n).value  # noqa: E731
        self.config = DetectorConfig(min_size_px=g('min_size_px'), max_size_px=g('max_size_px'),
                                     polarity=g('polarity'), min_snr=g('min_snr'))
        self.shape, self.expected = g('shape'), int(g('expected_count'))
        if self.shape not in ('',) + SHAPES or self.expected < 0:
            raise ValueError('shape must be "", circle or cross; expected_count >= 0')
        self.continuous, self.timeout = g('continuous'), float(g('service_timeout_s'))
        self._latest = None
        self._new_image = threading.Condition()
        self.marks_pub = self.create_publisher(MarkArray, 'marks', 10)
        self.create_subscription(Image, 'camera/image_raw', self.on_image, LATEST_IMAGE,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.create_service(DetectMarks, 'mark_detector/detect', self.on_detect,
                            callback_group=MutuallyExclusiveCallbackGroup(), qos_profile=SERVICES)

    def on_image(self, msg):
        with self._new_image:
            self._latest = msg
            self._new_image.notify_all()
        if self.continuous:
            self.marks_pub.publish(self._detect(msg, self.shape, self.expected))

    def _detect(self, msg, shape, expected) -> MarkArray:
        try:
            detection = detect_marks(image_from_message(msg), self.config, shape, expected)
            return marks_as_message(detection.marks, msg.header)
        except MachineAlignmentError as exc:
            self.get_logger().warning(f'detection failed: {exc}', throttle_duration_sec=5.0)
            return marks_as_message([], msg.header, status=str(exc))
        except Exception as exc:  # a bug must not take the camera chain down
            self.get_logger().error(f'internal error in detection: {exc!r}')
            return marks_as_message([], msg.header, status=f'internal error: {exc!r}')

    def on_detect(self, request, response):
        requested = self.get_clock().now()
        with self._new_image:
            fresh = self._new_image.wait_for(
                lambda: self._latest is not None
                and Time.from_msg(self._latest.header.stamp) > requested, timeout=self.timeout)
            image = self._latest
        if not fresh:
            response.success = False
            response.message = f'no camera image within {self.timeout:.1f} s'
            return response
        if request.shape not in ('',) + SHAPES:
            response.success, response.message = False, f'unknown shape {request.shape!r}'
            return response
        result = self._detect(image, request.shape, int(request.expected_count))
        self.marks_pub.publish(result)
        response.marks = result
        response.success = result.status == 'ok'
        response.message = result.status
        return response


def main(args=None):
    run_node(MarkDetectorNode, args, threads=3)


if __name__ == '__main__':
    main()
