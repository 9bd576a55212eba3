from pathlib import Path

from setuptools import find_packages, setup

package_name = 'clis_modules'
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
    description='CLIS learning modules (plug-ins: innate, view, place, wall) and the arbiter.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'innate = clis_modules.module_node:main_innate',
            'view = clis_modules.module_node:main_view',
            'place = clis_modules.module_node:main_place',
            'arbiter = clis_modules.arbiter_node:main',
            'module = clis_modules.module_node:main',
        ],
        # the module plug-ins (clis_modules.core.plugin; docs/modules.md)
        'clis.modules': [
            'innate = clis_modules.plugins.innate:Innate',
            'view = clis_modules.plugins.view:View',
            'place = clis_modules.plugins.place:Place',
            'wall = clis_modules.plugins.wall:Wall',
        ],
    },
)
