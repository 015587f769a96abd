#!/bin/sh
# Build the C controller example into an FMU (no Python): gcc compiles own_pd_c/own_pd_c.c against the FMI 2.0
# headers, zip packs binary + modelDescription.xml + source.
#
#   sh examples/own_controller/build_c.sh [FMI2_HEADERS_DIR] [OUT_DIR]
#
# FMI2_HEADERS_DIR: where fmi2Functions.h, fmi2FunctionTypes.h, fmi2TypesPlatform.h are (default: fmpy's copy,
# found with `python3 -c "import fmpy, os; print(os.path.dirname(fmpy.__file__))"`/c-code; or the headers from
# https://github.com/modelica/fmi-standard/tree/v2.0.4/headers). OUT_DIR: default build/examples.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
headers=${1:-$(python3 -c "import fmpy, os; print(os.path.join(os.path.dirname(fmpy.__file__), 'c-code'))")}
out=$(mkdir -p "${2:-build/examples}" && cd "${2:-build/examples}" && pwd)
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/binaries/linux64" "$stage/sources"
gcc -shared -fPIC -O2 -std=c99 -Wall -Wextra -fvisibility=default -I "$headers" \
    -o "$stage/binaries/linux64/OwnPDC.so" "$here/own_pd_c/own_pd_c.c"
cp "$here/own_pd_c/modelDescription.xml" "$stage/"
cp "$here/own_pd_c/own_pd_c.c" "$stage/sources/"
rm -f "$out/OwnPDC.fmu"
(cd "$stage" && zip -q -r "$out/OwnPDC.fmu" modelDescription.xml binaries sources)
echo "$out/OwnPDC.fmu"
