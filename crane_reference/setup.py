"""ament_python package setup for crane_reference.

The ROS executable ``node`` (what ``ros2 run crane_reference node`` starts) is installed as a data
file into ``lib/crane_reference`` instead of a console script, so that a plain ``pip install`` never
puts a program called ``node`` on the user's PATH (it would shadow Node.js).  The PyPI builds of ROS 2
Jazzy are an optional extra (``ros``): on a machine with a ROS distribution, rclpy and the message
packages come from there.  ``setup.py install`` (``colcon build``) ends by compiling the kernels of the
installed package (:class:`InstallAndCompile`).
"""

import os
import subprocess
import sys
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.install import install

PACKAGE = "crane_reference"


class InstallAndCompile(install):
    """``setup.py install`` (what ``colcon build`` runs for an ament_python package), then the package's numba
    kernels compiled from the installed sources, as a C++ package compiles at build: numba keys its cache on the
    sources' path, so that the installed node's first start loads them instead of compiling for a minute or two.
    A failure (numba missing at build time) leaves the compile to the first start, with a warning; a staged
    install (``--root``: a wheel's or a distribution package's build, whose files move) is not compiled."""

    def run(self) -> None:
        super().run()
        if self.root is not None:
            return
        lib = os.path.abspath(self.install_lib)
        command = (f"import sys; sys.path.insert(0, {lib!r}); from {PACKAGE}.cli import main; "
                   "sys.exit(main(['compile']))")
        prefix = os.path.abspath(self.install_data)  # its share directory: the config files the warm-up loads
        env = dict(os.environ, AMENT_PREFIX_PATH=os.pathsep.join(filter(None, (prefix,
                                                                               os.environ.get("AMENT_PREFIX_PATH")))))
        print(f"{PACKAGE}: compiling the kernels of the package installed in {lib}")
        if subprocess.run([sys.executable, "-c", command], env=env, check=False).returncode != 0:
            print(f"{PACKAGE}: WARNING: the kernels were not compiled; the first start compiles them "
                  "(or run `crane-reference compile`)", file=sys.stderr)

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "benchmarks"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.urdf")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/rviz", glob("rviz/*.rviz")),
        (f"lib/{PACKAGE}", ["scripts/node", "scripts/plant", "scripts/controller"]),
    ],
    python_requires=">=3.10",
    install_requires=[
        "setuptools",
        "numpy>=1.24",
        "scipy>=1.10",
        "numba>=0.58",
        "PyYAML>=6",
        "matplotlib>=3.6",
        "rosbags>=0.10",
        "tqdm>=4.60",
        "urdf-parser-py>=0.0.4",
        "pandas>=2",
        "pyarrow>=14",
        "dask[distributed]>=2024.1",
    ],
    extras_require={
        "ros": [
            "ros-jazzy-rclpy[fastrtps]",
            "ros-jazzy-common-interfaces",
            "ros-jazzy-std-srvs",
        ],
        "test": ["pytest>=7", "pytest-xdist>=3", "pin>=3", "mcap>=1.1", "ruff>=0.5", "import-linter>=2.1"],
    },
    zip_safe=True,
    maintainer="crane_reference maintainers",
    maintainer_email="crane-reference@example.org",
    description="Programmed constrained motion of a flexible-boom crane as a ROS 2 reference.",
    license="Apache-2.0",
    cmdclass={"install": InstallAndCompile},
    entry_points={
        "console_scripts": [
            "crane-reference = crane_reference.cli:main",
        ],
    },
)
