#!/usr/bin/env python3
"""Lines per function and per class in C++ sources (a small stand-in for lizard, which Debian
does not package): prints JSON with, per file, its line count and its longest functions and
classes. Heuristic: comments and literals are stripped, namespace braces are transparent, a
brace opened at namespace or class level after a ')' starts a function (its lambdas count
towards it), one after 'class X'/'struct X' starts a class (its inline member functions are
counted too).

  tools/function_lengths.py [--top N] FILE...
"""
import argparse
import json
import re


def strip(src):
    out, i, n = [], 0, len(src)
    while i < n:
        c = src[i]
        if src.startswith('//', i):
            j = src.find('\n', i)
            i = n if j < 0 else j
        elif src.startswith('/*', i):
            j = src.find('*/', i + 2)
            seg = src[i:(n if j < 0 else j + 2)]
            out.append('\n' * seg.count('\n'))
            i = n if j < 0 else j + 2
        elif src.startswith('R"', i):
            m = re.match(r'R"([^(]*)\(', src[i:])
            end = src.find(')' + m.group(1) + '"', i)
            seg = src[i:end + len(m.group(1)) + 2]
            out.append('""' + '\n' * seg.count('\n'))
            i = end + len(m.group(1)) + 2
        elif c in '"\'':
            j = i + 1
            while j < n and src[j] != c:
                j += 2 if src[j] == '\\' else 1
            out.append(c + c)
            i = j + 1
        else:
            out.append(c)
            i += 1
    return ''.join(out)


def scan(path):
    text = strip(open(path, encoding='utf-8').read())
    lines = text.count('\n') + (0 if text.endswith('\n') else 1)
    stack = []  # (kind, name, start_line)
    found = []
    header, line = '', 1
    for c in text:
        if c == '\n':
            line += 1
        if c == '{':
            h = ' '.join(header.split())
            in_func = any(k == 'function' for k, _, _ in stack)
            if in_func:
                kind, name = 'block', ''
            elif re.search(r'\bnamespace\b[^;{}]*$', h) or re.search(r'extern\s*""$', h):
                kind, name = 'namespace', ''
            elif re.search(r'\b(class|struct|union)\s+(\w+)[^;(){}]*$', h) and not h.endswith(')'):
                kind, name = 'class', re.search(r'\b(class|struct|union)\s+(\w+)[^;(){}]*$', h).group(2)
            elif ')' in h:
                m = re.search(r'([\w:~]+(?:operator\S*)?)\s*\([^()]*(?:\([^()]*\)[^()]*)*\)[^()]*$', h)
                kind, name = 'function', (m.group(1) if m else h[-40:])
            else:
                kind, name = 'block', ''
            stack.append((kind, name, line))
            header = ''
        elif c == '}':
            if stack:
                kind, name, start = stack.pop()
                if kind in ('function', 'class'):
                    found.append({'kind': kind, 'name': name, 'line': start, 'lines': line - start + 1})
            header = ''
        elif c == ';':
            header = ''
        else:
            header += c
    return lines, found


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--top', type=int, default=3)
    ap.add_argument('files', nargs='+')
    a = ap.parse_args()
    out = []
    for f in a.files:
        n, found = scan(f)
        funcs = sorted((x for x in found if x['kind'] == 'function'), key=lambda x: -x['lines'])
        classes = sorted((x for x in found if x['kind'] == 'class'), key=lambda x: -x['lines'])
        out.append({'file': f, 'lines': n, 'functions': len(funcs),
                    'longest_functions': [{k: x[k] for k in ('name', 'line', 'lines')} for x in funcs[:a.top]],
                    'longest_classes': [{k: x[k] for k in ('name', 'line', 'lines')} for x in classes[:a.top]]})
    print(json.dumps(out, indent=1))


if __name__ == '__main__':
    main()
