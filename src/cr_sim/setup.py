import os
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'cr_sim'
HERE = Path(__file__).resolve().parent

# The project's config/ (parameter files, arena, DDS profile) is installed with cr_sim,
# the package every other one depends on; config_dir() finds it there.
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
    description='Cyber Rodent arena simulator: seeded core, Gymnasium env, ROS 2 node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sim = cr_sim.sim_node:main',
        ],
        # Gymnasium's plugin group (loaded by gymnasium 0.26-0.29; 1.x loads no plugins: the
        # venv's start-up hook registers CRNav-v0 instead, cr_sim.gym_plugin, docs/gym.md)
        'gymnasium.envs': [
            '__root__ = cr_sim.gym_plugin:register_envs',
        ],
    },
)
