#!/usr/bin/env bash
# Keep the committed model files from travelling to a lent GPU machine, whose tool sends the whole working tree
# (tracked files and untracked ones git does not ignore) and refuses more than 64 MiB; the reference runs' model
# files (results/*/model.hbeo) are most of the tree, and the device job needs none of them.
#     bash scripts/device_tree.sh slim       before the device call: untrack them in the index and ignore them in
#                                            .git/info/exclude (the files stay on disk, nothing is committed)
#     bash scripts/device_tree.sh restore    after it: track them again, drop the exclude lines
# `slim` refuses a tree with staged changes (restore would mix them up); commit first.
set -euo pipefail
cd "$(dirname "$0")/.."
MARK="# hbeo device_tree.sh slim"
EXCLUDE=$(git rev-parse --git-path info/exclude)
case "${1:-}" in
  slim)
    if ! git diff --cached --quiet; then
      echo "error: the index has staged changes; commit or unstage them first" >&2; exit 2
    fi
    if grep -qF "$MARK" "$EXCLUDE" 2>/dev/null; then
      echo "error: already slim (run: bash scripts/device_tree.sh restore)" >&2; exit 2
    fi
    mapfile -t files < <(git ls-files -- 'results/*/model.hbeo')
    [ ${#files[@]} -gt 0 ] || { echo "nothing to leave behind"; exit 0; }
    git rm -q --cached -- "${files[@]}"
    mkdir -p "$(dirname "$EXCLUDE")"
    for f in "${files[@]}"; do printf '%s: /%s\n/%s\n' "$MARK" "$f" "$f" >> "$EXCLUDE"; done
    echo "left behind (still on disk): ${files[*]}"
    ;;
  restore)
    mapfile -t files < <(grep -F "$MARK: /" "$EXCLUDE" 2>/dev/null | sed "s|^$MARK: /||")
    [ ${#files[@]} -gt 0 ] || { echo "not slim: nothing to restore"; exit 0; }
    tmp=$(mktemp)
    grep -vF "$MARK" "$EXCLUDE" > "$tmp" || true
    for f in "${files[@]}"; do grep -vxF "/$f" "$tmp" > "$tmp.2" || true; mv "$tmp.2" "$tmp"; done
    cat "$tmp" > "$EXCLUDE" && rm -f "$tmp"
    git reset -q -- "${files[@]}"
    echo "tracked again: ${files[*]}"
    ;;
  *)
    echo "usage: bash scripts/device_tree.sh slim|restore" >&2; exit 2
    ;;
esac
