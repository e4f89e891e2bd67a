#!/usr/bin/env bash
# Create the venvs beside this repo's README and install their requirements (idempotent).
#
#   bash tools/setup.sh [5.2] [4.2]     # default: both
#
#   .venv/      Blender 5.2 LTS (bpy 5.2, Python 3.13): requirements-5.2.txt. Everything runs here.
#   .venv-4.2/  Blender 4.2 LTS (bpy 4.2, Python 3.11): requirements-4.2.txt. The oldest supported Blender.
#
# A venv is (re)installed when its requirement files change, and made anew when its Python is not
# the one its Blender needs. Set PYTHON313 / PYTHON311 to choose the interpreters.
set -euo pipefail
cd "$(dirname "$0")/.."

# find_python 3.13: print the path of a working python3.13 (PATH, then pyenv's versions).
find_python() {
  local v=$1 var c
  var=PYTHON${v/./}
  for c in "${!var:-}" "$(command -v "python$v" 2>/dev/null || true)" \
           $(ls -d "${PYENV_ROOT:-$HOME/.pyenv}"/versions/"$v".*/bin/python"$v" 2>/dev/null | sort -rV); do
    if [ -n "$c" ] && "$c" -c "import sys; sys.exit(sys.version_info[:2] != (${v/./, }))" 2>/dev/null; then
      # `python3.13 -c` run through a pyenv shim works only here; keep the real path.
      "$c" -c 'import sys; print(sys.executable)'
      return 0
    fi
  done
  echo "error: Python $v is needed; install it or set $var=/path/to/python$v" >&2
  return 1
}

# setup_venv DIR PYTHON_VERSION REQUIREMENTS_FILE
setup_venv() {
  local dir=$1 version=$2 req=$3 py want
  if [ -e "$dir" ] && ! "$dir/bin/python" -c "import sys; sys.exit(sys.version_info[:2] != (${version/./, }))" 2>/dev/null; then
    if [ -L "$dir" ]; then
      echo "error: $dir is a link to a venv without Python $version; remove the link and run again" >&2
      return 1
    fi
    echo "$dir: not a Python $version venv; making it anew"
    rm -rf "$dir"
  fi
  if [ ! -x "$dir/bin/python" ]; then
    py=$(find_python "$version")
    "$py" -m venv "$dir"
  fi
  want=$(cat requirements.txt "$req" | sha256sum | cut -d' ' -f1)
  if [ "$(cat "$dir/.requirements.sha" 2>/dev/null)" != "$want" ]; then
    echo "$dir: installing $req (bpy is about 400 MB the first time)"
    "$dir/bin/python" -m pip install --quiet --upgrade pip
    "$dir/bin/python" -m pip install --quiet -r "$req"
    echo "$want" > "$dir/.requirements.sha"
  fi
}

blenders=("$@")
[ ${#blenders[@]} -gt 0 ] || blenders=(5.2 4.2)
for b in "${blenders[@]}"; do
  case "$b" in
    5.2) setup_venv .venv 3.13 requirements-5.2.txt ;;
    4.2) setup_venv .venv-4.2 3.11 requirements-4.2.txt ;;
    *) echo "error: unknown Blender '$b' (5.2 or 4.2)" >&2; exit 2 ;;
  esac
done
