from setuptools import find_packages, setup

package_name = 'husky_world'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'README.md']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='CLIS maintainers',
    maintainer_email='clis@example.org',
    description="Clearpath's Husky in a PyBullet world, behind the standard ROS 2 topics.",
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'world = husky_world.world_node:main',
        ],
    },
)
