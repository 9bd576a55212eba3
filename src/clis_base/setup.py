import os
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'clis_base'
HERE = Path(__file__).resolve().parent

# The project's config/ (parameter files, arena, robot profiles, DDS profile) is installed with
# clis_base, the package every other one depends on; clis_base.params.config_dir() finds it.
CONFIG = sorted(str(p) for p in (HERE.parent.parent / 'config').glob('*.*'))
ROBOTS = sorted(str(p) for p in (HERE.parent.parent / 'config' / 'robots').glob('*.yaml'))

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', [os.path.relpath(c, HERE) for c in CONFIG]),
        ('share/' + package_name + '/config/robots',
         [os.path.relpath(c, HERE) for c in ROBOTS]),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='CLIS maintainers',
    maintainer_email='clis@example.org',
    description='The bottom of the CLIS workspace: parameters, ticks, the agent stream and the '
                'ROS 2 node plumbing.',
    license='Apache-2.0',
)
