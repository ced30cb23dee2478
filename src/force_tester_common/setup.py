from glob import glob

from setuptools import find_packages, setup

package_name = 'force_tester_common'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        # the rigs' parameter files (docs/nodes.md, "Several rigs on one machine"); config/rigs at the
        # workspace root links here. get_package_share_directory(package_name) + '/config/rigs'
        ('share/' + package_name + '/config/rigs', glob('config/rigs/*.yaml')),
        # ros2 launch force_tester_common graph.launch.xml | rig.launch.xml (docs/nodes.md) and their defaults
        ('share/' + package_name + '/launch', glob('launch/*.launch.xml')),
        ('share/' + package_name + '/config/launch', glob('config/launch/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='Force tester team',
    maintainer_email='team@force-tester.invalid',
    description='ROS glue shared by the force tester nodes',
    license='Apache-2.0',
)
