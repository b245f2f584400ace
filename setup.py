"""ament_python package `aeropend_ros`; it also installs the ROS-free library `aeropend_core`."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'aeropend_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(include=['aeropend_core', 'aeropend_core.*', 'aeropend_ros', 'aeropend_ros.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.json') + glob('config/*.xml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    package_data={'aeropend_core': ['py.typed']},
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='aeropend developers',
    maintainer_email='aeropend@example.invalid',
    description='Aeropendulum rig: recording, weak-SINDy identification and missing-physics diagnosis.',
    license='MIT',
    python_requires='>=3.11',
    entry_points={
        'console_scripts': [
            'aeropend = aeropend_core.cli:main',
            'sim_node = aeropend_ros.sim_node:main',
            'excitation_node = aeropend_ros.excitation_node:main',
            'recorder_node = aeropend_ros.recorder_node:main',
            'identification_node = aeropend_ros.identification_node:main',
            'serial_bridge_node = aeropend_ros.serial_bridge_node:main',
            'foxglove_node = aeropend_ros.foxglove_node:main',
        ],
        # verbs of the `aeropend` command that need ROS; the core finds them here and never names aeropend_ros
        'aeropend.verbs': [
            'run = aeropend_ros.cli.run',
            'monitor = aeropend_ros.cli.monitor',
        ],
    },
)
