# The README's two commands: `make demo` and `make test`. Everything else is a helper for them.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test venv system-deps suitesparse bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml | suitesparse
	$(BIN)/python -m pip install --quiet -e '.[test]'
	# aniposelib, the peer reader of our calibration.toml in the tests, without its opencv-contrib-python: that
	# wheel ships the same cv2 package as our headless one and would overwrite it (pyproject.toml says more)
	$(BIN)/python -m pip install --quiet --no-deps 'aniposelib==0.8.0'
	# Pose2Sim, caliscope and Blender (bpy), whose own code reads our interop files and export-people's TRC files in
	# the tests, without their dependencies: their opencv-python wheels would overwrite our cv2, Pose2Sim's pull a GUI
	# and pose estimation (PySide6, openvino, rtmlib), bpy pins numpy 1.26 (pyproject.toml says more)
	$(BIN)/python -m pip install --quiet --no-deps 'pose2sim==0.10.49' 'caliscope==0.11.8' 'bpy==5.0.1'
	touch $(STAMP)

venv: $(STAMP)

# SuiteSparse's headers and libraries, which scikit-sparse (the bundle adjustment's sparse Cholesky, CHOLMOD) is built
# against, and an optimised BLAS for CHOLMOD's dense fronts (Debian's default is the reference BLAS, ~10x slower)
suitesparse:
	@if [ ! -f /usr/include/suitesparse/cholmod.h ] || ! ldconfig -p | grep -q 'openblas'; then \
	  if command -v apt-get >/dev/null 2>&1; then \
	    SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	    $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libsuitesparse-dev libopenblas0-pthread >/dev/null; \
	  else echo "make: cannot install libsuitesparse-dev and libopenblas0-pthread (no apt-get); install them by hand" >&2; exit 1; fi; \
	fi

# System packages the tests need: libltc (the reference LTC codec, cross-checked through ctypes), and Debian's
# chromium with its chromedriver (the report page's browser tests, tests/test_report_page.py).
system-deps: suitesparse
	@if ! ldconfig -p | grep -q 'libltc\.so'; then \
	  if command -v apt-get >/dev/null 2>&1; then \
	    SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	    $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libltc11 >/dev/null; \
	  else echo "make: cannot install libltc11 (no apt-get); install it by hand" >&2; exit 1; fi; \
	fi
	@if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then \
	  if command -v apt-get >/dev/null 2>&1; then \
	    SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	    $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq chromium chromium-driver >/dev/null; \
	  else echo "make: cannot install chromium and chromium-driver (no apt-get); install them by hand" >&2; exit 1; fi; \
	fi

demo: $(STAMP)
	$(BIN)/dome-calib demo

test: system-deps $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist loadfile

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
