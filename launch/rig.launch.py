"""The aeropend graph on the real rig: serial_bridge_node (USB to the Arduino Mega), excitation_node,
identification_node, recorder_node, and with ``foxglove:=true`` foxglove_node (ws://127.0.0.1:8765).

Every node reads its shipped parameter file ``share/aeropend_ros/config/<node>.yaml`` (keyed ``/**/<node>``, so it
also applies inside a namespace; put your calibration there, see ``aeropend calibrate``); the launch arguments
override single parameters. To split the graph across machines (the bridge on a small computer next to the rig, the
analysis elsewhere, same ROS_DOMAIN_ID), start the parts with ``bridge:=false`` or ``excitation:=false
identification:=false recorder:=false``, with the same ``namespace`` on both machines. Topic names are relative:
``namespace:=rig1`` puts the rig on ``/rig1/aeropend/...`` (as ``aeropend run --rig rig1``), and its recorder records
only that rig.

    ros2 launch aeropend_ros rig.launch.py port:=/dev/serial/by-id/usb-Arduino_Mega-if00
    ros2 launch aeropend_ros rig.launch.py port:=/dev/ttyACM0 namespace:=rig1 duration:=120.0 foxglove:=true
    ros2 launch aeropend_ros rig.launch.py --show-args
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
        DeclareLaunchArgument('port', default_value='/dev/ttyACM0',
                              description='serial port of the Arduino (a /dev/serial/by-id/... name survives '
                                          'replugging)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description="ROS namespace of every node, one per rig on a shared network: '' = the "
                                          'default graph (topics /aeropend/...), NAME = rig NAME (topics '
                                          '/NAME/aeropend/..., as aeropend run --rig NAME)'),
        DeclareLaunchArgument('model_effects', default_value="['']",
                              description="effects in the identified model, e.g. \"['angle_offset']\"; "
                                          "\"['']\" = none"),
        DeclareLaunchArgument('record', default_value='bags',
                              description='folder in which the bag folder aeropend_<date>_<time> is created'),
        DeclareLaunchArgument('bridge', default_value='true', description='start the serial bridge on this machine'),
        DeclareLaunchArgument('excitation', default_value='true', description='play the excitation schedule'),
        DeclareLaunchArgument('identification', default_value='true', description='identify online'),
        DeclareLaunchArgument('recorder', default_value='true', description='record the topics to an MCAP bag'),
        DeclareLaunchArgument('duration', default_value='60.0',
                              description='length of the Latin-hypercube excitation [s]'),
        DeclareLaunchArgument('seed', default_value='1', description='seed of the excitation schedule'),
        DeclareLaunchArgument('max_duty', default_value='0.7',
                              description='duty cap of the bridge (the firmware clamps too) [fraction]'),
        DeclareLaunchArgument('foxglove', default_value='false',
                              description='serve the live graph to Foxglove (WebSocket, foxglove-sdk)'),
        DeclareLaunchArgument('foxglove_port', default_value='8765', description='port of the Foxglove server'),
        Node(package='aeropend_ros', executable='serial_bridge_node', name='serial_bridge_node',
             namespace=LaunchConfiguration('namespace'), output='screen',
             condition=IfCondition(LaunchConfiguration('bridge')),
             parameters=[PathJoinSubstitution([config, 'config', 'serial_bridge_node.yaml']), {
                 'port': LaunchConfiguration('port'),
                 'max_duty': ParameterValue(LaunchConfiguration('max_duty'), value_type=float),
             }]),
        Node(package='aeropend_ros', executable='excitation_node', name='excitation_node',
             namespace=LaunchConfiguration('namespace'), output='screen',
             condition=IfCondition(LaunchConfiguration('excitation')),
             parameters=[PathJoinSubstitution([config, 'config', 'excitation_node.yaml']), {
                 'duration': ParameterValue(LaunchConfiguration('duration'), value_type=float),
                 'seed': ParameterValue(LaunchConfiguration('seed'), value_type=int),
                 'duty_cap': ParameterValue(LaunchConfiguration('max_duty'), value_type=float),
             }]),
        Node(package='aeropend_ros', executable='identification_node', name='identification_node',
             namespace=LaunchConfiguration('namespace'), output='screen',
             condition=IfCondition(LaunchConfiguration('identification')),
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
