from glob import glob

from setuptools import find_packages, setup

package_name = 'global_loc'

setup(
    name=package_name,
    version='0.1.0',
    # the runtime only: the benchmark and the test and demo harnesses run from the source tree
    packages=find_packages(include=['global_loc', 'global_loc.*'],
                           exclude=['global_loc.bench', 'global_loc.bench.*',
                                    'global_loc.testing', 'global_loc.testing.*']),
    package_data={'global_loc.sim': ['*.urdf']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/maps', glob('maps/*.yaml') + glob('maps/*.pgm') + glob('maps/*.png')),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='global_loc developers',
    maintainer_email='dev@global-loc.invalid',
    description='Single-scan global localization in a known map (ROS 2 Jazzy).',
    license='BSD-3-Clause',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'server = global_loc.ros.server:main',
            'test_global_loc = global_loc.ros.client:main',
            'sim = global_loc.ros.sim_node:main',
            'localize = global_loc.offline.cli:main',
        ],
    },
)
