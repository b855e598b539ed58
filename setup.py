"""Which packages fieldkit installs: its code, plus two data folders mapped in by name.

The rest of the build configuration is in pyproject.toml. This file exists for one thing
pyproject.toml cannot say: `packages.find` names a package by the folder it sits in, while the
device profiles, Buzz scripts and systemd templates stay at the repository's top level (where
users, docs and tests look for them) yet must install inside fieldkit, as
`fieldkit.device_profiles`, `fieldkit.buzz_scripts` and `fieldkit.systemd`, so that
`importlib.resources` finds them in a wheel and in the editable install alike (see
fieldkit/resources.py).
"""

from setuptools import find_namespace_packages, setup

DATA_PACKAGES = {
    "fieldkit.device_profiles": "device_profiles",
    "fieldkit.buzz_scripts": "buzz_scripts",
    "fieldkit.systemd": "systemd",
}

# Each data package with its sub-folders (include/, graphs/, examples/) as packages of their own,
# so setuptools copies their files without warning that they are importable yet unlisted.
data_packages = [
    f"{package}{sub}"
    for package, folder in DATA_PACKAGES.items()
    for sub in ["", *(f".{p}" for p in find_namespace_packages(where=folder))]
]

setup(
    packages=find_namespace_packages(include=["bvm*", "fieldkit*"]) + data_packages,
    package_dir=DATA_PACKAGES,
)
