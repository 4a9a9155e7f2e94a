"""Simulated printer vision chain for a full ROS 2 install: ros2 launch machine_alignment printer_sim.launch.py"""
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription([
        Node(package='machine_alignment', executable='gantry_sim', name='gantry_sim'),
        Node(package='machine_alignment', executable='camera_sim', name='camera_sim',
             parameters=[{'scene': 'dot_plate', 'rate_hz': 4.0}]),
        Node(package='machine_alignment', executable='mark_detector', name='mark_detector',
             parameters=[{'continuous': False}]),
        Node(package='machine_alignment', executable='vision_calibrator', name='vision_calibrator'),
    ])
