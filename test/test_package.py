"""package.xml, setup.py and setup.cfg agree with each other and with the code."""
import ast
import configparser
import glob
import importlib
import os
import sys
import xml.etree.ElementTree as ElementTree

import pytest
from setuptools._distutils.core import run_setup

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = 'collision_node'
# Python dependencies by import name: the rosdep key package.xml uses for each.
ROSDEP_KEYS = {'numpy': 'python3-numpy', 'numba': 'python3-numba', 'pytest': 'python3-pytest',
               'hypothesis': 'python3-hypothesis', 'trimesh': 'python3-trimesh'}
# Imports without a rosdep key, declared as pip extras in setup.py instead: pip names.
PIP_NAMES = {'fcl': 'python-fcl', 'matplotlib': 'matplotlib', 'coal': 'coal',
             'mujoco': 'mujoco', 'pinocchio': 'pin', 'ray': 'ray'}


@pytest.fixture(scope='module')
def manifest():
    return ElementTree.parse(os.path.join(REPO, 'package.xml')).getroot()


@pytest.fixture(scope='module')
def distribution():
    cwd = os.getcwd()
    os.chdir(REPO)  # setup.py globs config/ relative to the working directory
    try:
        return run_setup('setup.py', stop_after='init')
    finally:
        os.chdir(cwd)


def depends(manifest, *kinds):
    return {element.text.strip() for kind in kinds for element in manifest.iter(kind)}


def imported_modules(folder):
    """Return the top-level names of the modules imported under ``folder``, with a file.

    Imports guarded by ``except ImportError`` are optional and left out.
    """
    names = {}
    for path in glob.glob(os.path.join(REPO, folder, '**', '*.py'), recursive=True):
        with open(path) as source:
            tree = ast.parse(source.read(), path)
        optional = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Try) and any(
                    _names_import_error(handler.type) for handler in node.handlers):
                optional.update(id(inner) for statement in node.body
                                for inner in ast.walk(statement))
        for node in ast.walk(tree):
            if id(node) in optional:
                continue
            if isinstance(node, ast.Import):
                found = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                found = [node.module]
            else:
                continue
            for name in found:
                names.setdefault(name.split('.')[0], os.path.relpath(path, REPO))
    return names


def _names_import_error(handler_type):
    if isinstance(handler_type, ast.Tuple):
        return any(_names_import_error(element) for element in handler_type.elts)
    return isinstance(handler_type, ast.Name) and handler_type.id in (
        'ImportError', 'ModuleNotFoundError')


def test_name_version_and_license_agree(manifest, distribution):
    assert manifest.findtext('name') == distribution.metadata.name == PACKAGE
    assert manifest.findtext('version') == distribution.metadata.version
    assert manifest.findtext('license') == distribution.metadata.license
    with open(os.path.join(REPO, 'LICENSE')) as license_text:  # the text package.xml promises
        assert 'Apache License\n                           Version 2.0' in license_text.read()
    maintainer = manifest.find('maintainer')
    assert maintainer.text.strip() == distribution.metadata.maintainer
    assert maintainer.get('email') == distribution.metadata.maintainer_email
    assert manifest.find('export').findtext('build_type') == 'ament_python'


def test_data_files_install_the_index_marker_manifest_license_and_config(distribution):
    data_files = dict(distribution.data_files)
    assert data_files['share/ament_index/resource_index/packages'] == ['resource/' + PACKAGE]
    assert os.path.isfile(os.path.join(REPO, 'resource', PACKAGE))
    assert data_files['share/' + PACKAGE] == ['package.xml', 'LICENSE']
    assert 'config/default.yaml' in data_files['share/%s/config' % PACKAGE]


def test_scripts_go_where_ros2_run_looks():
    config = configparser.ConfigParser()
    config.read(os.path.join(REPO, 'setup.cfg'))
    assert config['develop']['script_dir'] == '$base/lib/' + PACKAGE
    assert config['install']['install_scripts'] == '$base/lib/' + PACKAGE


def test_every_console_script_names_a_function(distribution):
    for line in distribution.entry_points['console_scripts']:
        name, target = (part.strip() for part in line.split('='))
        module, function = target.split(':')
        assert callable(getattr(importlib.import_module(module), function, None)), line


def third_party(names):
    local = {PACKAGE, 'conftest'} | {
        os.path.splitext(os.path.basename(path))[0]
        for path in glob.glob(os.path.join(REPO, 'test', '*.py'))}
    return {name: path for name, path in names.items()
            if name not in sys.stdlib_module_names and name not in local}


def test_package_imports_are_run_dependencies(manifest, distribution):
    run = depends(manifest, 'exec_depend', 'depend')
    extras = {name for names in distribution.extras_require.values() for name in names}
    missing = [
        '%s (imported in %s)' % (name, path)
        for name, path in sorted(third_party(imported_modules(PACKAGE)).items())
        if ROSDEP_KEYS.get(name, name) not in run and PIP_NAMES.get(name) not in extras]
    assert not missing, 'add to package.xml <exec_depend> (or setup.py extras): %s' % missing


def test_test_imports_are_test_dependencies(manifest, distribution):
    declared = depends(manifest, 'exec_depend', 'depend', 'test_depend')
    extras = set(distribution.extras_require.get('test', []))
    missing = [
        '%s (imported in %s)' % (name, path)
        for name, path in sorted(third_party(imported_modules('test')).items())
        if ROSDEP_KEYS.get(name, name) not in declared and PIP_NAMES.get(name) not in extras
        and name != 'setuptools']  # setup.py's own dependency, used here to read it
    assert not missing, 'add to package.xml <test_depend> (or setup.py extras): %s' % missing


def test_ci_runs_the_readme_test_command():
    """CI (.ci/run) sets up its own venv and runs exactly the test command the README gives."""
    with open(os.path.join(REPO, 'README.md')) as readme:
        text = readme.read()
    command = 'bash .ci/setup-venv && .venv/bin/python -m pytest -q'
    assert '\n%s\n' % command in text
    with open(os.path.join(REPO, '.ci', 'run')) as run:
        steps = [line for line in run.read().splitlines()
                 if line and not line.startswith('#') and not line.startswith(('set ', 'cd '))]
    assert ' && '.join(steps) == command
