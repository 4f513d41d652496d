"""Install script for nbv_prob_cnn (ament_python layout, also a plain pip package)."""

import runpy
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "nbv_prob_cnn"
NODES = runpy.run_path(str(Path(__file__).parent / PACKAGE / "ros" / "__init__.py"))["NODES"]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={
        PACKAGE: ["sensing/*.cl", "gain/*.cl", "bench/*.cl", "ros/*.xml", "ros/config/*.yaml", "ros/config/*.rviz"]
        + [f"weights/*.{ext}" for ext in ("pt", "md", "csv", "png")]
    },
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    python_requires=">=3.10",
    install_requires=["numpy", "scipy", "matplotlib", "tqdm"],
    zip_safe=False,
    maintainer="nbv_prob_cnn maintainers",
    maintainer_email="maintainers@nbv-prob-cnn.dev",
    description="Probabilistic next best view planning with a completion CNN (ROS 2 + core library)",
    license="BSD-3-Clause",
    entry_points={
        "console_scripts": [
            "nbv = nbv_prob_cnn.cli:main",
            *(f"{node} = nbv_prob_cnn.ros.{node}:main" for node in NODES),
        ],
    },
)
