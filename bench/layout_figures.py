"""Layout figures for a commit or the work tree: lines per folder, the largest files and functions.

Usage: python3 bench/layout_figures.py [REV]   (the redesign compared 2971405 with its final commit;
figures in the closing note of issue 11). Function lengths of C++ are a brace-matching estimate."""
import subprocess, sys, re, ast, collections
rev = sys.argv[1] if len(sys.argv) > 1 else None
def files():
    if rev:
        out = subprocess.run(["git", "ls-tree", "-r", "--name-only", rev], capture_output=True, text=True).stdout.split()
    else:
        out = subprocess.run(["git", "ls-files"], capture_output=True, text=True).stdout.split()
    return [f for f in out if f.endswith((".py", ".cpp", ".h", ".pyi")) and f.startswith(("pipeline/", "formats/", "tools/", "tests/"))]
def text(f):
    if rev:
        return subprocess.run(["git", "show", f"{rev}:{f}"], capture_output=True, text=True).stdout
    return open(f).read()
per = collections.Counter(); largest = []; funcs = []
for f in files():
    t = text(f); n = t.count("\n")
    d = "/".join(f.split("/")[:2]) if f.startswith(("pipeline/", "tools/hirad/")) and f.count("/") > 1 else f.split("/")[0]
    if f.startswith("tools/hirad/"):
        parts = f.split("/"); d = "/".join(parts[:3]) if len(parts) > 3 else "tools/hirad"
    if f.startswith("tests/"):
        parts = f.split("/"); d = "/".join(parts[:3]) if len(parts) > 3 else "/".join(parts[:2])
    per[d] += n; largest.append((n, f))
    if f.endswith(".py"):
        try:
            for node in ast.walk(ast.parse(t)):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    funcs.append((node.end_lineno - node.lineno + 1, f"{f}:{node.name}"))
        except SyntaxError: pass
    else:
        # C++: a function body starts at a line ending in '{' at depth 0 or 1 (class members) and ends when depth returns
        lines = t.splitlines(); depth = 0; start = None; name = None; sdepth = 0
        for i, line in enumerate(lines):
            code = re.sub(r'//.*', '', line); code = re.sub(r'"(\\.|[^"\\])*"', '""', code)
            if start is None and code.rstrip().endswith("{") and "(" in code and depth <= 2 and not re.match(r'\s*(if|for|while|switch|namespace|struct|class|enum)\b', code) and "=" not in code.split("(")[0]:
                start, name, sdepth = i, code.strip()[:70], depth
            depth += code.count("{") - code.count("}")
            if start is not None and depth <= sdepth:
                funcs.append((i - start + 1, f"{f}:{name}")); start = None
for d, n in sorted(per.items()): print(f"{n:7d}  {d}")
print("total", sum(per.values()))
print("largest files:", sorted(largest)[-3:])
print("largest functions:", sorted(funcs)[-4:])
