"""Development tools: test benches, benchmarks and the helpers that write docs/. The nodes never
import this subpackage; it ships so that ``scripts/bench_*.py`` and the tests share one copy."""
