"""ament_python package machine_alignment: works with colcon on a ROS install and with pip in a venv."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'machine_alignment'

NODES = {
    'camera_sim': 'printer_alignment.nodes.camera_sim',
    'gantry_sim': 'printer_alignment.nodes.gantry_sim',
    'mark_detector': 'printer_alignment.nodes.mark_detector',
    'vision_calibrator': 'printer_alignment.nodes.vision_calibrator',
    'stage_sim': 'printer_alignment.nodes.stage_sim',
    'stage_calibrator': 'printer_alignment.nodes.stage_calibrator',
    'aligner': 'printer_alignment.nodes.aligner',
    'hexapod_sim': 'hexapod_calib.nodes.hexapod_sim',
    'pose_sensor_sim': 'hexapod_calib.nodes.pose_sensor_sim',
    'hexapod_calibrator': 'hexapod_calib.nodes.hexapod_calibrator',
    'grid_calibrator': 'grid_calib.nodes.grid_calibrator',
    'platform_sim': 'platform_calib.nodes.platform_sim',
    'laser_tracker_sim': 'platform_calib.nodes.laser_tracker_sim',
    'platform_calibrator': 'platform_calib.nodes.platform_calibrator',
    'five_axis_sim': 'dispenser_calib.nodes.five_axis_sim',
    'five_axis_calibrator': 'dispenser_calib.nodes.five_axis_calibrator',
    'recorder': 'calib_core.nodes.recorder',
    'player': 'calib_core.nodes.player',
}

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(include=['calib_core*', 'printer_alignment*', 'hexapod_calib*',
                                    'grid_calib*', 'platform_calib*', 'dispenser_calib*',
                                    'machine_alignment*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    package_data={'machine_alignment': ['fastdds_services.xml'],
                  'hexapod_calib': ['descriptions/*.yaml'],
                  'platform_calib': ['descriptions/*.yaml']},
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='machine_alignment maintainers',
    maintainer_email='maintainers@machine-alignment.invalid',
    description='Vision-based alignment and kinematic calibration of precision machines.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [f'{name} = {module}:main' for name, module in NODES.items()]
        + ['machine-align = machine_alignment.cli:main'],
    },
)
