"""ament_python package `aeropend_ros`; it also installs the ROS-free library `aeropend_core`."""
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'aeropend_ros'
here = Path(__file__).resolve().parent


def requirements(name: str, ros: bool = False) -> list[str]:
    """The package lines of a requirements file (comments, `-r` includes and, unless `ros`, the ros-jazzy-* wheels
    dropped: on a ROS install those come from apt, as package.xml says)."""
    path = here / name
    if not path.exists():           # an sdist without the file: nothing to add
        return []
    lines = (line.split('#')[0].strip() for line in path.read_text().splitlines())
    return [line for line in lines if line and not line.startswith('-') and (ros or not line.startswith('ros-'))]


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
    # what a user of the nodes and the command needs (ROS itself from the ROS install, or `pip install .[ros]`)
    install_requires=['setuptools', *requirements('requirements.txt')],
    extras_require={'ros': [r for r in requirements('requirements.txt', ros=True) if r.startswith('ros-')],
                    'dev': requirements('requirements-dev.txt')},
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
