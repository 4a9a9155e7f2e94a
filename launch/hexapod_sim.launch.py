"""Simulated hexapod cell for a full ROS 2 install: ros2 launch machine_alignment hexapod_sim.launch.py"""
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription([
        Node(package='machine_alignment', executable='hexapod_sim', name='hexapod_sim'),
        Node(package='machine_alignment', executable='pose_sensor_sim', name='pose_sensor_sim'),
        Node(package='machine_alignment', executable='hexapod_calibrator',
             name='hexapod_calibrator'),
    ])
