from setuptools import find_packages, setup

package_name = 'force_correction'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='Force tester team',
    maintainer_email='team@force-tester.invalid',
    description='force_correction of the force tester workspace',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'correction_node = force_correction.correction_node:main',
            'validator_node = force_correction.validator_node:main',
            'correction_graph = force_correction.composed:main',
        ],
    },
)
