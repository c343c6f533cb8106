"""ament_python build of softgrip_ros (src layout).

Console entry points install into ``lib/softgrip_ros`` (see setup.cfg), where
``ros2 run`` looks; ``package.xml``, the ament index marker and ``config/`` go
into ``share/`` so nodes find their defaults through ``ament_index_python``.
"""
from glob import glob

from setuptools import find_packages, setup

PACKAGE_NAME = "softgrip_ros"

setup(
    name=PACKAGE_NAME,
    version="0.1.0",
    package_dir={"": "src"},
    packages=find_packages("src"),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE_NAME}"]),
        (f"share/{PACKAGE_NAME}", ["package.xml"]),
        (f"share/{PACKAGE_NAME}/config", sorted(f for f in glob("config/*") if "." in f)),
        (f"share/{PACKAGE_NAME}/config/scenes", sorted(glob("config/scenes/*.yaml"))),
        (f"share/{PACKAGE_NAME}/config/clamp_force", sorted(glob("config/clamp_force/*.yaml"))),
        (f"share/{PACKAGE_NAME}/urdf", sorted(glob("urdf/*.xacro"))),
        (f"share/{PACKAGE_NAME}/launch", sorted(glob("launch/*.launch.py"))),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="softgrip_ros maintainers",
    maintainer_email="softgrip@example.com",
    description="ROS 2 driver suite for a two-finger pneumatic soft gripper.",
    license="Apache-2.0",
    extras_require={"test": ["pytest", "hypothesis"], "reference": ["pyelastica==1.0.0"],
                    "fe": ["scikit-fem==12.0.2", "gmsh==4.15.2", "ngsolve==6.2.2608",
                           "netgen-mesher==6.2.2608"]},
    entry_points={
        "console_scripts": [
            "pressure_controller = softgrip_ros.nodes.pressure_controller:main",
            "sim_device = softgrip_ros.nodes.sim_device:main",
            "estimator = softgrip_ros.nodes.estimator:main",
            "kinematics = softgrip_ros.nodes.kinematics:main",
            "grasp_manager = softgrip_ros.nodes.grasp_manager:main",
            "controller = softgrip_ros.nodes.controller:main",
            "softgrip = softgrip_ros.cli:main",
            "softgrip_identify = softgrip_ros.tools.identify:main",
            "softgrip_calibrate = softgrip_ros.tools.calibrate:main",
            "softgrip_check_device = softgrip_ros.tools.check_device:main",
            "softgrip_record = softgrip_ros.tools.record:main",
            "softgrip_replay = softgrip_ros.tools.replay:main",
        ],
        # python-can finds this interface by name: can.Bus(interface="softgrip_ipc", channel=...)
        "can.interface": [
            "softgrip_ipc = softgrip_ros.canbus.softgrip_ipc:SoftgripIpcBus",
        ],
    },
)
