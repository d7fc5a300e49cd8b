"""The fuzz suite's count of cases tried, printed at the end of the test session."""


def pytest_terminal_summary(terminalreporter):
    from tests.reliability import test_fuzz

    if test_fuzz.counts:
        counts = test_fuzz.counts
        terminalreporter.write_line("fuzz cases tried: " + ", ".join(f"{kind} {n}" for kind, n in sorted(counts.items()))
                                    + f"; {sum(counts.values())} in all")
