from setuptools import find_packages, setup

package_name = 'cr_sim'

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
