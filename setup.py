"""Map the design card's top-level folders onto the `litevloc.*` namespace.

`cli/` -> `litevloc.cli`, `runtime/` -> `litevloc.runtime`, `pipelines/` -> `litevloc.pipelines`, `hw/` ->
`litevloc.hw`, `models/` -> `litevloc.models`, `config/` -> `litevloc.config`, `base/` -> `litevloc.base`
(the bottom layer: errors, geometry, parameter dataclasses).
Sub-packages are discovered, so adding a folder with an `__init__.py` needs no edit here.
Works for normal and editable (`pip install -e .`) installs.
"""

from setuptools import find_packages, setup

FOLDERS = ("cli", "runtime", "experiments", "pipelines", "hw", "sim", "models", "config", "base")

packages: list[str] = []
package_dir: dict[str, str] = {}
for folder in FOLDERS:
    packages.append(f"litevloc.{folder}")
    package_dir[f"litevloc.{folder}"] = folder
    packages += [f"litevloc.{folder}.{sub}" for sub in find_packages(folder)]

setup(
    packages=packages,
    package_dir=package_dir,
    # py.typed (PEP 561) in every top-level folder: the litevloc.* packages ship their annotations
    package_data={**{f"litevloc.{folder}": ["py.typed"] for folder in FOLDERS},
                  "litevloc.config": ["py.typed", "presets/*.yaml", "worlds/*.yaml"]},
    include_package_data=False,
)
