"""Only what pyproject.toml cannot say: the Modelica sources and the thesis scenarios
(``modelica/`` and ``scenarios/``, kept at the top of the checkout) are shipped inside
the wheel as ``cosim/_modelica`` and ``cosim/_scenarios``, where :mod:`cosim.paths`
finds them in an installed package. Every folder is listed as a package (the C
sources' too), so that setuptools has no folder to guess about."""
from setuptools import find_namespace_packages, setup


def tree(package: str, folder: str) -> list[str]:
    """``package`` (the folder ``folder``) and one package per folder below it."""
    return [package] + [f"{package}.{p}" for p in find_namespace_packages(where=folder)]


setup(packages=[*find_namespace_packages(include=["cosim", "cosim.*"], exclude=["*__pycache__"]),
                *tree("cosim._modelica", "modelica"), *tree("cosim._scenarios", "scenarios")],
      package_dir={"cosim._modelica": "modelica", "cosim._scenarios": "scenarios"})
