# dpe5g: `make book` and `make test` do all set-up themselves on a fresh clone (see README.md).
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SOURCES := $(shell find dpe5g -name '*.py' -not -path '*/__pycache__/*') $(wildcard dpe5g/data/* figures/trials/*)
CHAPTERS := $(wildcard chapters/*.md)
BOOK_SRC := $(wildcard book/*.md book/*.yml book/*.bib book/_static/* book/_ext/*.py) $(CHAPTERS)
HTML := book/_build/html/index.html

.PHONY: all setup reproduce figures book chapter lab test clean
all: book

setup: $(STAMP)

# The virtual environment: exact pins from environment.txt, the package installed editable.  --no-compile: pip
# byte-compiles nothing at install (on 2 CPUs the install took 58 s with it, 27 s without); Python compiles each module
# the first time it is imported and keeps it, so only the modules that run are compiled, once.
$(STAMP): environment.txt pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip==26.3
	$(BIN)/python -m pip install --quiet --no-compile -r environment.txt
	touch $@

# Ray-trace the city chapter's city, its solver-settings subsets, the density sweep's three networks and the second
# city (Sionna RT, about 37, 38, 47 and 7 minutes on 2 cores from scratch, skipped where current; needs Debian's libllvm19), recompute every
# experiment of the results store (figures/trials) from its seeds, report every stored trial that
# differs, rewrite the store; then the figure baselines (PNG + data JSON) and README's tables from it.  Run it after a
# change that the store's verification in `make test` fails on.  SCHEDULER=tcp://host:8786 (or DPE5G_SCHEDULER) runs
# the chunks (the Monte Carlo's, and the city's batches of UEs: city.trace_chunks, which resumes a stopped trace
# from .cache/trace) on a Dask cluster, WORKERS=N on a LocalCluster of N processes (tracing: about 15 GB each).  It refuses to run while dpe5g/,
# environment.txt or pyproject.toml differ from the commit (each entry records the commit whose code computed it):
# commit first, or ALLOW_DIRTY=1 (the entries then record a digest of the changes too).  `make figures` is the same.
reproduce: $(STAMP)
	$(BIN)/python -m dpe5g trace --progress $(if $(SCHEDULER),--scheduler $(SCHEDULER)) $(if $(WORKERS),--workers $(WORKERS))
	$(BIN)/python -m dpe5g reproduce $(if $(SCHEDULER),--scheduler $(SCHEDULER)) $(if $(WORKERS),--workers $(WORKERS)) $(if $(ALLOW_DIRTY),--allow-dirty)
	$(BIN)/python -m dpe5g figures --update-baselines
	$(BIN)/python scripts/readme_tables.py

figures: reproduce

# Build the HTML book, its chapters executed two at a time (scripts/build_book.py: Sphinx's parallel read; BOOK_JOBS=1
# for one); a chapter is re-executed when it changed, every chapter when dpe5g/ or environment.txt changed
# (book/_ext/dpe5g_book.py clears the execution cache then),
# and warnings are errors.  The chapters record the Monte Carlo runs they ask for in RUN_LOG (tests/book/test_warm.py
# checks that `dpe5g warm`, which prefills the cache, knows them all).
RUN_LOG := .cache/book-runs.jsonl
$(HTML): $(STAMP) $(BOOK_SRC) $(SOURCES)
	@mkdir -p .cache; rm -f $(RUN_LOG)
	DPE5G_RUN_LOG=$(CURDIR)/$(RUN_LOG) $(BIN)/python scripts/build_book.py build . --config book/_config.yml \
		--toc book/_toc.yml --path-output book -W -n --keep-going
	test -f $@ && touch $@

book: $(HTML)

# Execute one chapter on its own: make chapter CH=05 [SMOKE=1] -> book/_build/chapters/05_rmse_vs_snr.ipynb, with its run time.
chapter: $(STAMP)
	@test -n "$(CH)" || { echo "make chapter: say which, e.g. make chapter CH=05 (add SMOKE=1 for a quick run)" >&2; exit 2; }
	$(BIN)/python scripts/run_chapter.py "$(CH)" $(if $(filter 1,$(SMOKE)),--smoke)

# A chapter as a live notebook: make lab [CH=05] -> JupyterLab (pinned in environment-lab.txt, installed into .venv on
# first use, about a minute) with the chapters opening as notebooks (jupytext); each cell runs in chapters/ as the book
# runs it, and a number the prose glues shows in its cell's output (dpe5g.figures.registry.glue_value).
LAB_STAMP := $(VENV)/.lab-installed
$(LAB_STAMP): environment-lab.txt book/lab/overrides.json $(STAMP)
	$(BIN)/python -m pip install --quiet --no-compile -r environment-lab.txt
	mkdir -p $(VENV)/share/jupyter/lab/settings
	cp book/lab/overrides.json $(VENV)/share/jupyter/lab/settings/overrides.json
	touch $@

lab: $(LAB_STAMP)
	where=$$($(if $(CH),$(BIN)/python scripts/run_chapter.py --which "$(CH)",echo chapters)) && $(BIN)/jupyter lab $(if $(filter 0,$(shell id -u)),--allow-root) "$$where"

# Every test: unit + property tests, bad input, figure-diff against the committed baselines, browser test of the book.
# The tests that need neither the book nor the figures' Monte Carlo results run at low priority while the book builds
# (its Monte Carlo leaves part of the CPUs idle); those in tests/book/ (figure-diff, browser) start when it is built,
# beside the rest of them (a browser waits on pages more than it computes).  Each test file runs in one pytest worker
# (pyproject.toml's --dist loadfile): the browser opens each page once, not once per worker (the book's tests: 72 s
# -> 57 s), and a file's tests share the programs they compile (the others, on an idle machine: 310 s -> 299 s).  Low
# priority takes more than `nice` where Linux groups processes by session (autogroup): Jupyter starts each chapter's kernel in a
# session of its own, and the scheduler shares the CPUs equally between sessions whatever their nice values, so the
# tests run in a session of their own whose group is niced to 19 (without setsid or autogroup: plain nice).
# One seed for the whole run's check of the results store (the chapters' samples and tests/simulation/test_store.py's), printed
# first; DPE5G_VERIFY_SEED=N make test repeats a run's samples.
# Each pytest worker computes on one thread (as each chapter's kernel does, scripts/build_book.py): two workers and
# two kernels share 2 CPUs, and thread pools sized to every CPU in each of them spin while they wait for work.
ONE_THREAD := env OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 XLA_FLAGS="$$XLA_FLAGS --xla_cpu_multi_thread_eigen=false"
UNIT_LOG := .cache/pytest-unit.log
BOOK_LOG := .cache/pytest-book.log
test: export DPE5G_VERIFY_SEED := $(or $(DPE5G_VERIFY_SEED),$(shell od -An -N4 -tu4 /dev/urandom | awk '{print $$1 % 2147483648}'))
test: $(STAMP)
	@mkdir -p .cache
	@echo "results store verification seed: $$DPE5G_VERIFY_SEED (DPE5G_VERIFY_SEED=$$DPE5G_VERIFY_SEED make test repeats its samples)"
	lowpri() { if command -v setsid > /dev/null; then \
	    setsid -w sh -c '{ echo 19 > /proc/self/autogroup; } 2> /dev/null; exec nice -n 19 "$$@"' sh "$$@"; \
	  else nice -n 19 "$$@"; fi; }; \
	lowpri $(ONE_THREAD) $(BIN)/python -m pytest --ignore=tests/book > $(UNIT_LOG) 2>&1 & unit=$$!; \
	book=0; $(MAKE) --no-print-directory book || book=$$?; \
	booktests=0; if test $$book -eq 0; then \
	  $(ONE_THREAD) $(BIN)/python -m pytest tests/book > $(BOOK_LOG) 2>&1 || booktests=$$?; \
	else echo "make book failed: the tests in tests/book were not run" > $(BOOK_LOG); fi; \
	status=0; wait $$unit || status=$$?; \
	cat $(UNIT_LOG) $(BOOK_LOG); \
	test $$book -eq 0 -a $$status -eq 0 -a $$booktests -eq 0

clean:
	rm -rf book/_build figure-diff
