"""What a viewer shows of a recorded run (calib_core/nodes/scene.py): TF, PoseStamped and
CompressedImage messages that a bag reader decodes with the standard definitions, and
the five-axis frames, which must put the board where the nominal model's camera sees it."""
import cv2
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from scipy.spatial.transform import Rotation
from std_msgs.msg import Header

from calib_core.bags import BagWriter, decode_bag
from calib_core.errors import InvalidInputError
from calib_core.frames import planar
from calib_core.nodes.scene import (
    IMAGE_TYPE, POSE_TYPE, TF_TOPIC, TF_TYPE, compressed_image, pose_stamped, transforms_cdr)
from dispenser_calib.core.model import camera_points, nominal_frames, nominal_model


def _chain(frames: list, child: str) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of ``child`` in the root frame, composing the TF tree's parent links."""
    links = {c: (p, Rotation.from_quat(q).as_matrix(), np.asarray(t)) for p, c, t, q in frames}
    rotation, translation = np.eye(3), np.zeros(3)
    while child in links:
        parent, r, t = links[child]
        rotation, translation = r @ rotation, r @ translation + t
        child = parent
    return rotation, translation


@pytest.mark.parametrize('pose', [(0.0, 0.0, 0.0, 0.0, 0.0), (0.01, -0.02, 0.005, 0.3, 1.2),
                                  (-0.03, 0.015, -0.01, -0.5, -2.5)])
def test_five_axis_frames_agree_with_the_nominal_model(pose):
    """Board points through the TF chain (table in machine, camera in machine) land where
    the nominal model's camera frame has them: the frames' signs and order are the model's."""
    frames = nominal_frames(np.array(pose))
    r_table, t_table = _chain(frames, 'table')
    r_camera, t_camera = _chain(frames, 'camera')
    points = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.008, 0.002]])
    in_camera = (points @ r_table.T + t_table - t_camera) @ r_camera
    np.testing.assert_allclose(in_camera, camera_points(nominal_model(), points,
                                                        np.array(pose))[0], atol=1e-12)


def test_messages_decode_from_a_bag_with_the_standard_definitions(tmp_path):
    header = Header(frame_id='base')
    header.stamp.sec = 5
    pose = pose_stamped(header, *planar(0.01, -0.02, 0.3))
    tf = transforms_cdr(5 * 10**9 + 7, [('base', 'platform', *planar(0.01, -0.02, 0.3))])
    frame = np.random.default_rng(0).integers(0, 255, (48, 64), dtype=np.uint8)
    with BagWriter(tmp_path / 'bag') as bag:
        for topic, msgtype, cdr in (
                ('/pose', POSE_TYPE, serialize_message(pose)), (TF_TOPIC, TF_TYPE, tf),
                ('/frame', IMAGE_TYPE, serialize_message(compressed_image(frame, header, 'png')))):
            bag.add_topic(topic, msgtype)
            bag.write(topic, 1, cdr)
    decoded = {topic: msg for topic, _, msg in decode_bag(tmp_path / 'bag')}
    assert decoded['/pose'].header.frame_id == 'base'
    assert decoded['/pose'].pose.position.x == pytest.approx(0.01)
    q = decoded[TF_TOPIC].transforms[0].transform.rotation
    assert Rotation.from_quat([q.x, q.y, q.z, q.w]).as_rotvec()[2] == pytest.approx(0.3)
    assert decoded[TF_TOPIC].transforms[0].child_frame_id == 'platform'
    stamp = decoded[TF_TOPIC].transforms[0].header.stamp
    assert (stamp.sec, stamp.nanosec) == (5, 7)
    image = decoded['/frame']
    assert image.format == 'png'
    np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(bytes(image.data), np.uint8),
                                               cv2.IMREAD_GRAYSCALE), frame)   # lossless


def test_jpeg_frames_are_smaller_and_close_and_bad_frames_are_refused():
    rng = np.random.default_rng(1)
    frame = np.clip(cv2.GaussianBlur(rng.normal(128, 40, (256, 320)), (0, 0), 3), 0,
                    255).astype(np.uint8)
    jpeg = compressed_image(frame, Header())
    png = compressed_image(frame, Header(), 'png')
    assert jpeg.format == 'jpeg' and len(jpeg.data) < len(png.data)
    back = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert np.abs(back.astype(float) - frame).mean() < 2.0           # grey levels
    with pytest.raises(InvalidInputError, match='jpeg or png'):
        compressed_image(frame, Header(), 'bmp')
    with pytest.raises(InvalidInputError, match='uint8'):
        compressed_image(frame.astype(float), Header())
    with pytest.raises(InvalidInputError, match='finite'):
        pose_stamped(Header(), [np.nan, 0, 0], [0, 0, 0, 1])
