"""olado._registry.LazyRegistry: a table of names that imports a component only when it is looked up."""

import subprocess
import sys

import pytest

from olado._registry import Entry, LazyRegistry
from olado.errors import ConfigError
from fixtures import REPO

NEVER = "olado_test_module_that_does_not_exist"


def table():
    return LazyRegistry("widget", {
        "json": Entry("json.decoder:JSONDecoder", "decodes JSON", requires=("json",)),
        "ghost": Entry(f"{NEVER}:Ghost", "needs a missing module", requires=(NEVER, "json"), install="pip install ghost"),
        "plain": "json.encoder:JSONEncoder",
    }, key="widget")


def test_listing_imports_nothing():
    code = ("import sys\nfrom olado._registry import LazyRegistry, Entry\n"
            "r = LazyRegistry('x', {'a': Entry('email.mime.text:MIMEText', 'a summary', requires=('email',))})\n"
            "assert list(r) == ['a'] and len(r) == 1 and 'a' in r and r.summary('a') == 'a summary'\n"
            "assert r.missing('a') == [] and r.target('a') == 'email.mime.text:MIMEText'\n"
            "assert 'email.mime.text' not in sys.modules\n"
            "assert r['a'].__name__ == 'MIMEText' and 'email.mime.text' in sys.modules\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0, out.stderr


def test_lookup_and_entries():
    r = table()
    from json.decoder import JSONDecoder
    from json.encoder import JSONEncoder

    assert r["json"] is JSONDecoder and r["plain"] is JSONEncoder
    assert r.entry("plain") == Entry("json.encoder:JSONEncoder") and r.summary("plain") == ""
    assert r.missing("json") == [] and r.missing("ghost") == [NEVER]
    assert r.entry("ghost").install == "pip install ghost"
    assert r.get("nope") is None and r.get("json") is JSONDecoder
    with pytest.raises(ImportError):
        r["ghost"]


def test_unknown_name_is_a_config_error_naming_the_allowed_ones():
    with pytest.raises(ConfigError) as exc:
        table()["nope"]
    assert "unknown widget 'nope'" in str(exc.value) and "key 'widget'" in str(exc.value)
    assert exc.value.allowed == "json, ghost, plain"
    for call in (table().entry, table().target, table().summary, table().missing):
        with pytest.raises(ConfigError):
            call("nope")


def test_add_and_remove():
    r = table()

    class Local:
        pass

    r.add("local", Local)
    assert r["local"] is Local and r.target("local").endswith(":test_add_and_remove.<locals>.Local")
    r.add("local", "json.decoder:JSONDecoder")
    assert r["local"].__name__ == "JSONDecoder"
    r.remove("local")
    assert "local" not in r and list(r) == ["json", "ghost", "plain"]
    with pytest.raises(ConfigError):
        r.remove("local")
