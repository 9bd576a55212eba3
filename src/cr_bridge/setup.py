from pathlib import Path

from setuptools import find_packages, setup

package_name = 'cr_bridge'
HERE = Path(__file__).resolve().parent

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
    maintainer='CLIS maintainers',
    maintainer_email='clis@example.org',
    description='Robot interface for the real Cyber Rodent, with safety.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bridge = cr_bridge.bridge_node:main',
            'emulator = cr_bridge.emulator:main',
            'robot = cr_bridge.robot_node:main',
        ],
    },
)
