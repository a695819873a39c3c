"""The paper's experiments and reference scenarios (`uwsimnet experiment NAME`): scene generators, runs and
figures.  A face beside cli/: imports app/ and every room below, never cli/."""
