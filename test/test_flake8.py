"""ROS's flake8 check over the whole package: ament_flake8's rules plus the package's own.

ament_flake8.ini asks for 99 columns and the google import order, and ignores codes of the
plugins ROS installs with it (flake8-import-order, -quotes, -docstrings, ...). Without those
plugins flake8 skips their checks silently, so the first test insists on them. The package's
setup.cfg [flake8] section (what a plain ``flake8`` run reads) is laid over ament's file: it
names the application imports, which the google order puts in a group of their own.
"""
import configparser
from importlib import metadata
import os

import ament_flake8
from ament_flake8.main import main_with_errors
import pytest

PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
AMENT_CONFIG = os.path.join(os.path.dirname(ament_flake8.__file__), 'configuration',
                            'ament_flake8.ini')
# The flake8 plugins ament_flake8 depends on in ROS (its package.xml), as PyPI names.
ROS_FLAKE8_PLUGINS = (
    'flake8-blind-except', 'flake8-builtins', 'flake8-class-newline', 'flake8-comprehensions',
    'flake8-deprecated', 'flake8-docstrings', 'flake8-import-order', 'flake8-quotes')


def test_flake8_has_the_plugins_ros_runs_it_with():
    missing = []
    for name in ROS_FLAKE8_PLUGINS:
        try:
            metadata.distribution(name)
        except metadata.PackageNotFoundError:
            missing.append(name)
    assert not missing, 'pip install ' + ' '.join(missing)


def package_config(path):
    """Write ament's flake8 options with setup.cfg's laid over them to ``path``."""
    config = configparser.ConfigParser()
    config.read(AMENT_CONFIG)
    package = configparser.ConfigParser()
    package.read(os.path.join(PACKAGE_ROOT, 'setup.cfg'))
    overrides = package['flake8'] if package.has_section('flake8') else {}
    for key, value in overrides.items():
        if key == 'extend-ignore':  # both lists apply
            value = ','.join(filter(None, [config['flake8'].get(key), value]))
        config['flake8'][key] = value
    # One process: flake8's worker pool forks pytest, and a fork taken after another test
    # started rclpy's DDS threads can deadlock on a lock one of those threads held.
    config['flake8']['jobs'] = '1'
    with open(path, 'w') as file:
        config.write(file)
    return path


@pytest.mark.flake8
def test_flake8(monkeypatch, tmp_path):
    config = package_config(tmp_path / 'flake8.ini')
    # ament_flake8 excludes the folders starting with '.' or '_' (.venv, __pycache__) that
    # it finds under the working directory.
    monkeypatch.chdir(PACKAGE_ROOT)
    rc, errors = main_with_errors(argv=['--config', str(config)])
    assert rc == 0, 'Found %d code style errors / warnings:\n%s' % (
        len(errors), '\n'.join(errors))
