"""Install Ember into a real Blender with one command.

    python tools/install_addon.py [--blender /path/to/blender]

Builds the zip (tools/build_zip.py), then installs and enables the
right one for that Blender: the extension zip for 4.2 and later
(``blender --command extension install-file``), the legacy add-on zip for
3.4 - 4.1 (``preferences.addon_install`` + ``addon_enable`` + saved
preferences).  Afterwards Ember is in the render-engine list, and
``blender -b scene.blend -E EMBER -f 1`` works without ``--addons``.
Respects BLENDER_USER_CONFIG / BLENDER_USER_SCRIPTS (the tests use them).
"""
import argparse
import os
import re
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))

import build_zip  # noqa: E402

LEGACY_SCRIPT = """
import bpy, sys
zip_path = sys.argv[sys.argv.index('--') + 1]
bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module='ember')
bpy.ops.wm.save_userpref()
print('EMBER-INSTALLED')
"""


def blender_version(blender):
    out = subprocess.run([blender, "--version"], capture_output=True, text=True, check=True).stdout
    match = re.search(r"Blender (\d+)\.(\d+)", out)
    if not match:
        raise SystemExit(f"could not read the version of {blender}: {out[:200]!r}")
    return int(match.group(1)), int(match.group(2))


def zip_path(kind):
    """Build the zip afresh (a stale one in dist/ would install old code)."""
    built = build_zip.main(["--legacy" if kind == "addon" else "--extension"])
    return built[0]


def install(blender):
    version = blender_version(blender)
    if version >= (4, 2):
        cmd = [blender, "--command", "extension", "install-file", "-r", "user_default", "-e",
               zip_path("extension")]
        subprocess.run(cmd, check=True)
    else:
        cmd = [blender, "-b", "--factory-startup", "--python-expr", LEGACY_SCRIPT, "--", zip_path("addon")]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if "EMBER-INSTALLED" not in out.stdout:
            raise SystemExit(f"install into Blender {version} failed:\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}")
    print(f"Ember installed into Blender {version[0]}.{version[1]} ({blender})")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blender", default=shutil.which("blender"), help="Blender binary (default: on PATH)")
    args = parser.parse_args(argv)
    if not args.blender:
        raise SystemExit("no Blender binary found: pass --blender /path/to/blender")
    install(args.blender)


if __name__ == "__main__":
    main()
