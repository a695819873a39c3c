# Everything a fresh machine with Python 3.11 and make needs: `make paper` and `make test`.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: paper test lint bench clean native ros2-peers ros2-oracle bellhop

$(STAMP): pyproject.toml gli_clients/python/pyproject.toml
	@command -v $(PY) >/dev/null 2>&1 || { echo "need $(PY) on PATH (or make PY=python3)"; exit 2; }
	@echo "setup: a virtual environment in $(VENV) ($(PY))"
	@$(PY) -m venv $(VENV)
	@echo "setup: installing the package and its dependencies (pip; its log: $(VENV)/pip.log)"
	@{ $(BIN)/pip install -q --upgrade pip 'setuptools>=77' && $(BIN)/pip install -q -e gli_clients/python \
	   && $(BIN)/pip install -q -e '.[dev]'; } >$(VENV)/pip.log 2>&1 || { tail -n 30 $(VENV)/pip.log; exit 1; }
	@$(BIN)/python build_native.py
	@touch $(STAMP)

## The engine's hot modules compiled with mypyc (uwsimnet_zenoh/_native.py lists them; ~1 min): rebuilt when
## one of their sources changed, pure Python (said in one line) if the build fails
native: $(STAMP)
	@$(BIN)/python build_native.py

## The paper's physical-layer experiment (Section 3.1): trace, report and figures in out/phy-layer/
paper: native
	$(BIN)/uwsimnet experiment phy-layer --out out/phy-layer

## The test suite (what CI runs): two workers (pytest-xdist), each test file on one of them (module fixtures,
## routers and namespaces set up once per file); `make test TESTFLAGS=` runs it in one process
TESTFLAGS ?= -n 2 --dist loadfile
test: native
	$(BIN)/ruff check uwsimnet_zenoh tests bench
	$(BIN)/python -m pytest -q -rs -p no:cacheprovider $(TESTFLAGS)

lint: $(STAMP)
	$(BIN)/ruff check .

bench: native
	$(BIN)/python bench/bench_engine.py

## ROS 2 peers on the Zenoh versions rmw_zenoh ships (tests/test_ros2_live.py uses them when present)
ROS2_PEER_ZENOH := 1.4.0 1.6.2
ros2-peers:
	@for v in $(ROS2_PEER_ZENOH); do \
	  test -x .venv-zenoh-$$v/bin/python || { $(PY) -m venv .venv-zenoh-$$v && \
	    .venv-zenoh-$$v/bin/pip install -q eclipse-zenoh==$$v; } || exit 1; done

## Real ROS 2 Jazzy code (rclpy, rosidl) for tests/test_ros2_real.py and test_ros2_link_*.py: PyPI wheels + local message builds
ros2-oracle:
	@s=$$(cat uwsimnet_zenoh/ros2/interfaces/*/msg/*.msg uwsimnet_zenoh/ros2/interfaces/*/*.* tests/ros2_oracle/setup.sh \
	      | sha256sum | cut -c1-16); test "$$(cat .venv-ros2-jazzy/.stamp 2>/dev/null)" = "$$s" \
	  || { nice -n 10 bash tests/ros2_oracle/setup.sh .venv-ros2-jazzy $(PY) && echo $$s > .venv-ros2-jazzy/.stamp; }

## Bellhop (Acoustics Toolbox, GPL-3) for the channel model "bellhop" (docs/ocean.md): the aubellhop wheel ships
## a working binary; it needs Python >= 3.12, so it goes into a tool venv of its own. Run as a program, never imported.
BELLHOP_PY ?= python3.12
bellhop:
	@test -x .tools/bellhop/bin/python || { $(BELLHOP_PY) -c '' 2>/dev/null && $(BELLHOP_PY) -m venv .tools/bellhop \
	  || PYENV_VERSION=$$(pyenv versions --bare 2>/dev/null | grep '^3\.12' | tail -1) python3.12 -m venv .tools/bellhop; }
	.tools/bellhop/bin/pip install -q aubellhop==0.2.1
	@ls .tools/bellhop/lib/python3*/site-packages/aubellhop/bin/bellhop.exe

clean:
	rm -rf $(VENV) out .venv-zenoh-* .venv-ros2-jazzy build/native
	rm -f uwsimnet_zenoh/_native.json; find uwsimnet_zenoh -name "*.so" -delete
