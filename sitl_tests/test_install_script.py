"""scripts/install.py: pip's configuration carried over to uv faithfully, or not at all."""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType

import pytest

from sitl_tests.flight_fixtures import REPO


def _install() -> ModuleType:
    spec = importlib.util.spec_from_file_location("install", REPO / "scripts" / "install.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["install"] = module
    spec.loader.exec_module(module)
    return module


install = _install()

LISTING = """\
:env:.cert='/etc/ssl/certs/ca-certificates.crt'
:env:.default-timeout='180'
:env:.disable-pip-version-check='1'
:env:.find-links='/opt/wheels'
global.cert='/somewhere/else.crt'
global.constraint='/etc/xdg/pip/constraints.txt'
global.extra-index-url='file:///opt/pypi/simple file:///opt/pypi-more/simple'
global.find-links='/opt/other'
download.no-index='true'
install.trusted-host='mirror.local'
"""


def test_aliases_are_one_setting_and_empty_values_are_dropped_as_pip_does() -> None:
    settings = install.pip_settings(
        ":env:.default-timeout='180'\nglobal.timeout='10'\n:env:.index-url=''\n")
    assert settings == {"timeout": "180"}  # the variable wins, whichever name it has
    assert install.uv_call(settings).env == {"UV_HTTP_TIMEOUT": "180"}
    assert install.uv_call({"timeout": "60.0"}).env == {"UV_HTTP_TIMEOUT": "60"}
    for true in ("y", "t", "yes", "On", "1"):
        assert "--no-index" in install.uv_call({"no-index": true}).args


def test_pip_install_settings_env_over_install_over_global_other_commands_dropped() -> None:
    settings = install.pip_settings(LISTING)
    assert settings == {
        "cert": "/etc/ssl/certs/ca-certificates.crt",
        "timeout": "180",
        "disable-pip-version-check": "1",
        "find-links": "/opt/wheels",
        "constraint": "/etc/xdg/pip/constraints.txt",
        "extra-index-url": "file:///opt/pypi/simple file:///opt/pypi-more/simple",
        "trusted-host": "mirror.local",
    }


def test_uv_resolves_as_pip_does_with_every_index_constraint_and_certificate() -> None:
    call = install.uv_call(install.pip_settings(LISTING))
    # Nothing of uv's own configuration; pip's choice among indexes.
    assert call.args[:3] == ["--no-config", "--index-strategy", "unsafe-best-match"]
    pairs = list(zip(call.args[3::2], call.args[4::2], strict=True))
    assert sorted(pairs) == sorted([
        ("--find-links", "/opt/wheels"),
        ("--constraint", "/etc/xdg/pip/constraints.txt"),
        ("--extra-index-url", "file:///opt/pypi/simple"),
        ("--extra-index-url", "file:///opt/pypi-more/simple"),
        ("--allow-insecure-host", "mirror.local"),
    ])
    assert call.env == {"SSL_CERT_FILE": "/etc/ssl/certs/ca-certificates.crt",
                        "UV_HTTP_TIMEOUT": "180"}
    assert "--no-index" in install.uv_call({"no-index": "true"}).args
    assert "--no-index" not in install.uv_call({"no-index": "false"}).args


@pytest.mark.parametrize("key", ["proxy", "require-hashes", "only-binary", "pre"])
def test_a_setting_uv_would_not_honour_the_same_way_means_pip(key: str) -> None:
    with pytest.raises(install.Untranslatable) as e:
        install.uv_call({"find-links": "/opt/wheels", key: "x"})
    assert e.value.args == (key,)


def test_a_malformed_listing_line_is_skipped_and_a_bad_value_is_an_error() -> None:
    assert install.pip_settings("no equals sign\nnodot='x'\n") == {}
    with pytest.raises((SyntaxError, ValueError)):
        install.pip_settings("global.cert=not quoted")
