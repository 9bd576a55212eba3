from pathlib import Path

from setuptools import find_packages, setup

package_name = 'clis_app'
HERE = Path(__file__).resolve().parent

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('bin', ['scripts/clis']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='CLIS maintainers',
    maintainer_email='clis@example.org',
    description='The CLIS application: the clis command, graph launcher, headless runner, '
                'experiments, figures, bags, recorder, replay and the Foxglove live view.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'clis = clis_app.cli:main',
            'recorder = clis_app.bags.recorder_node:main',
            'foxglove = clis_app.live.foxglove_node:main',
        ],
    },
)
