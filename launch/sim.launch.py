"""The aeropend graph on the simulator: sim_node, excitation_node, identification_node, recorder_node, and with
``foxglove:=true`` foxglove_node (the live graph in Foxglove on ws://127.0.0.1:8765).

Every node reads its shipped parameter file ``share/aeropend_ros/config/<node>.yaml`` (keyed ``/**/<node>``, so it
also applies inside a namespace); the launch arguments below override single parameters. The topic names are
relative: ``namespace:=rig1`` puts the whole graph on ``/rig1/aeropend/...`` (``aeropend run --rig rig1`` does the
same), and its recorder records only that rig.

    ros2 launch aeropend_ros sim.launch.py
    ros2 launch aeropend_ros sim.launch.py effects:="['coulomb_friction=4']" model_effects:="['coulomb_friction']"
    ros2 launch aeropend_ros sim.launch.py namespace:=rig1 record:=/data/bags foxglove:=true
    ros2 launch aeropend_ros sim.launch.py --show-args
"""
import time
from typing import List

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    config = FindPackageShare('aeropend_ros')
    bag_name = 'aeropend_' + time.strftime('%Y%m%d_%H%M%S')
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='',
                              description="ROS namespace of every node, one per rig on a shared network: '' = the "
                                          'default graph (topics /aeropend/...), NAME = rig NAME (topics '
                                          '/NAME/aeropend/..., as aeropend run --rig NAME)'),
        DeclareLaunchArgument('effects', default_value="['angle_offset=0.05']",
                              description="hidden effects of the simulator, e.g. \"['coulomb_friction=4']\"; "
                                          "\"['']\" = none (aeropend effects lists them)"),
        DeclareLaunchArgument('model_effects', default_value="['']",
                              description="effects in the identified model, e.g. \"['angle_offset']\"; "
                                          "\"['']\" = none"),
        DeclareLaunchArgument('record', default_value='bags',
                              description='folder in which the bag folder aeropend_<date>_<time> is created'),
        DeclareLaunchArgument('recorder', default_value='true', description='record the topics to an MCAP bag'),
        DeclareLaunchArgument('duration', default_value='60.0',
                              description='length of the Latin-hypercube excitation [s]'),
        DeclareLaunchArgument('seed', default_value='1', description='seed of the excitation and the noise'),
        DeclareLaunchArgument('psnr_db', default_value='50.0',
                              description='simulated measurement noise [dB]; 0 = none'),
        DeclareLaunchArgument('realtime_factor', default_value='1.0',
                              description='simulation speed: 1 = real time, 4 = four times faster'),
        DeclareLaunchArgument('foxglove', default_value='false',
                              description='serve the live graph to Foxglove (WebSocket, foxglove-sdk)'),
        DeclareLaunchArgument('foxglove_port', default_value='8765', description='port of the Foxglove server'),
        Node(package='aeropend_ros', executable='sim_node', name='sim_node',
             namespace=LaunchConfiguration('namespace'), output='screen',
             parameters=[PathJoinSubstitution([config, 'config', 'sim_node.yaml']), {
                 'effects': ParameterValue(LaunchConfiguration('effects'), value_type=List[str]),
                 'seed': ParameterValue(LaunchConfiguration('seed'), value_type=int),
                 'psnr_db': ParameterValue(LaunchConfiguration('psnr_db'), value_type=float),
                 'realtime_factor': ParameterValue(LaunchConfiguration('realtime_factor'), value_type=float),
             }]),
        Node(package='aeropend_ros', executable='excitation_node', name='excitation_node',
             namespace=LaunchConfiguration('namespace'), output='screen',
             parameters=[PathJoinSubstitution([config, 'config', 'excitation_node.yaml']), {
                 'duration': ParameterValue(LaunchConfiguration('duration'), value_type=float),
                 'seed': ParameterValue(LaunchConfiguration('seed'), value_type=int),
             }]),
        Node(package='aeropend_ros', executable='identification_node', name='identification_node',
             namespace=LaunchConfiguration('namespace'), output='screen',
             parameters=[PathJoinSubstitution([config, 'config', 'identification_node.yaml']), {
                 'effects': ParameterValue(LaunchConfiguration('model_effects'), value_type=List[str]),
             }]),
        Node(package='aeropend_ros', executable='recorder_node', name='recorder_node',
             namespace=LaunchConfiguration('namespace'), output='screen',
             condition=IfCondition(LaunchConfiguration('recorder')),
             parameters=[PathJoinSubstitution([config, 'config', 'recorder_node.yaml']), {
                 'output': PathJoinSubstitution([LaunchConfiguration('record'), bag_name]),
             }]),
        Node(package='aeropend_ros', executable='foxglove_node', name='foxglove_node',
             namespace=LaunchConfiguration('namespace'), output='screen',
             condition=IfCondition(LaunchConfiguration('foxglove')),
             parameters=[PathJoinSubstitution([config, 'config', 'foxglove_node.yaml']), {
                 'port': ParameterValue(LaunchConfiguration('foxglove_port'), value_type=int),
             }]),
    ])
