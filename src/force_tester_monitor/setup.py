from glob import glob

from setuptools import find_packages, setup

package_name = 'force_tester_monitor'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/layouts', glob('layouts/*.json')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='Force tester team',
    maintainer_email='team@force-tester.invalid',
    description='force_tester_monitor of the force tester workspace',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'monitor_node = force_tester_monitor.monitor_node:main',
        ],
    },
)
