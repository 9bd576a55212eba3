import configparser
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'clis_modules'
HERE = Path(__file__).resolve().parent


def own_entry_points() -> dict[str, list[str]]:
    """The module plug-ins of the package, from the one file that lists them (which
    clis_modules.core.plugin also reads where this metadata is not installed)."""
    ini = configparser.ConfigParser(delimiters=('=',), interpolation=None)
    ini.optionxform = str
    path = HERE / package_name / 'plugins' / 'entry_points.txt'
    if not ini.read(path, encoding='utf-8'):
        raise FileNotFoundError(path)
    return {group: [f'{name} = {value}' for name, value in ini[group].items()]
            for group in ini.sections()}


setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name + '.plugins': ['entry_points.txt']},
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
            'detector = clis_modules.detector_node:main',
        ],
        # the module plug-ins, group clis.modules (clis_modules.core.plugin; docs/modules.md)
        **own_entry_points(),
    },
)
