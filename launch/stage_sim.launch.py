"""The simulated printer with its XY-Theta stage (dot plate removed; a vision calibration
in ``calibration/`` is published by vision_calibrator) for a full ROS 2 install:
ros2 launch machine_alignment stage_sim.launch.py"""
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription([
        Node(package='machine_alignment', executable='gantry_sim', name='gantry_sim'),
        Node(package='machine_alignment', executable='camera_sim', name='camera_sim',
             parameters=[{'scene': 'stage', 'rate_hz': 10.0}]),
        Node(package='machine_alignment', executable='mark_detector', name='mark_detector',
             parameters=[{'continuous': False}]),
        Node(package='machine_alignment', executable='vision_calibrator', name='vision_calibrator'),
        Node(package='machine_alignment', executable='stage_sim', name='stage_sim'),
        Node(package='machine_alignment', executable='stage_calibrator', name='stage_calibrator'),
        Node(package='machine_alignment', executable='aligner', name='aligner'),
    ])
