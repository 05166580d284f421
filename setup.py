"""Only what pyproject.toml cannot say: the Modelica sources (``modelica/``, kept at
the top of the checkout) are shipped inside the wheel as ``cosim/_modelica``, where
:func:`cosim.paths.modelica_dir` finds them in an installed package."""
from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["cosim", "cosim.*"]), "cosim._modelica"],
      package_dir={"cosim._modelica": "modelica"})
