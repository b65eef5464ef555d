"""The one thing pyproject.toml cannot say: drop the HIL scenarios from the wheel.

hil_tests is shipped for the rig behind `tcomp hil` (pyproject.toml, "The wheel ships the product"), but
its scenarios and pytest's conftest are modules of the same package, and setuptools' package-data
exclusions do not apply to modules. This build step leaves them out; tests/test_install.py lists the
wheel against the expected set.
"""
import fnmatch

from setuptools import setup
from setuptools.command.build_py import build_py

# (package, module-name patterns) left out of the wheel
TEST_MODULES = {"hil_tests": ("test_*", "conftest")}


class BuildProductOnly(build_py):
    """setuptools' build_py without the test modules of TEST_MODULES."""

    def find_package_modules(self, package, package_dir):
        patterns = TEST_MODULES.get(package, ())
        return [(pkg, module, path) for pkg, module, path in super().find_package_modules(package, package_dir)
                if not any(fnmatch.fnmatch(module, p) for p in patterns)]


setup(cmdclass={"build_py": BuildProductOnly})
