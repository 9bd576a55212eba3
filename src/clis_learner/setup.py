from pathlib import Path

from setuptools import find_packages, setup

package_name = 'clis_learner'
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
    description="CLIS learner: episode memory, resampling to each module's period, "
                'importance-sampled TD(lambda) and policy gradient, the learner node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'learner = clis_learner.learner_node:main',
        ],
    },
)
