#!/usr/bin/env bash
# Keep the committed results from travelling to a lent GPU machine, whose tool sends the whole working tree
# (tracked files and untracked ones git does not ignore) and refuses more than 64 MiB. The committed runs under
# results/ (model files, executed notebooks with figures inline, per-query evaluations) and the dated records in
# docs/history/ are most of the tree, and the device job and its benchmark read none of them (the job makes its
# own run folder).
#     bash maintainer/device_tree.sh slim       before the device call: untrack results/* (but results/README.md)
#                                            and docs/history/* in the index, move them into .device-aside/
#                                            (ignored in .git/info/exclude; a file that .gitignore un-ignores, as
#                                            results/quick-procedural/model.hbeo, would travel if only excluded
#                                            there), nothing is committed; then print what travels (exit 3 when it
#                                            still passes LIMIT_MIB, 64)
#     bash maintainer/device_tree.sh restore    after it: move them back, track them again, drop the exclude lines
# `slim` refuses a tree with staged changes (restore would mix them up); commit first. While slim, a pre-commit hook
# it adds (where the repository has none) refuses every commit: one would delete the results it untracked.
set -euo pipefail
cd "$(dirname "$0")/.."
MARK="# hbeo device_tree.sh slim"
EXCLUDE=$(git rev-parse --git-path info/exclude)
ASIDE=.device-aside
HOOK=$(git rev-parse --git-path hooks/pre-commit)
case "${1:-}" in
  slim)
    if ! git diff --cached --quiet; then
      echo "error: the index has staged changes; commit or unstage them first" >&2; exit 2
    fi
    if grep -qF "$MARK" "$EXCLUDE" 2>/dev/null; then
      echo "error: already slim (run: bash maintainer/device_tree.sh restore)" >&2; exit 2
    fi
    mapfile -t files < <(git ls-files -- 'results/*' 'docs/history/*' ':!:results/README.md')
    [ ${#files[@]} -gt 0 ] || { echo "nothing to leave behind"; exit 0; }
    git rm -q --cached -- "${files[@]}"
    mkdir -p "$(dirname "$EXCLUDE")"
    printf '%s\n/%s/\n' "$MARK" "$ASIDE" >> "$EXCLUDE"
    for f in "${files[@]}"; do
      printf '%s: /%s\n/%s\n' "$MARK" "$f" "$f" >> "$EXCLUDE"
      mkdir -p "$ASIDE/$(dirname "$f")" && mv "$f" "$ASIDE/$f"
    done
    if [ ! -e "$HOOK" ]; then
      mkdir -p "$(dirname "$HOOK")"
      printf '#!/bin/sh\n%s\necho "error: the tree is slim for a device call (results/ and docs/history/ untracked in the index): run bash maintainer/device_tree.sh restore, then commit" >&2\nexit 1\n' "$MARK" > "$HOOK"
      chmod +x "$HOOK"
    fi
    echo "left behind (in $ASIDE/ until restore): ${#files[@]} files under results/ and docs/history/"
    tree=$( { git ls-files -z; git ls-files -z -o --exclude-standard; } | du -cb --files0-from=- 2>/dev/null | tail -1 | cut -f1)
    limit=${LIMIT_MIB:-64}
    echo "to travel now: $((tree / 1048576)) MiB (working tree, with any carried folder inside it; limit $limit MiB)"
    [ "$tree" -le $((limit * 1048576)) ] || { echo "still over $limit MiB" >&2; exit 3; }
    ;;
  restore)
    mapfile -t files < <(grep -F "$MARK: /" "$EXCLUDE" 2>/dev/null | sed "s|^$MARK: /||")
    [ ${#files[@]} -gt 0 ] || { echo "not slim: nothing to restore"; exit 0; }
    for f in "${files[@]}"; do
      if [ -e "$ASIDE/$f" ]; then mkdir -p "$(dirname "$f")" && mv "$ASIDE/$f" "$f"; fi
    done
    find "$ASIDE" -depth -type d -empty -delete 2>/dev/null || true
    tmp=$(mktemp)
    grep -vF "$MARK" "$EXCLUDE" > "$tmp" || true
    grep -vxF "/$ASIDE/" "$tmp" > "$tmp.2" || true; mv "$tmp.2" "$tmp"
    for f in "${files[@]}"; do grep -vxF "/$f" "$tmp" > "$tmp.2" || true; mv "$tmp.2" "$tmp"; done
    cat "$tmp" > "$EXCLUDE" && rm -f "$tmp"
    git reset -q -- "${files[@]}"
    if grep -qF "$MARK" "$HOOK" 2>/dev/null; then rm -f "$HOOK"; fi
    echo "tracked again: ${#files[@]} files"
    ;;
  *)
    echo "usage: bash maintainer/device_tree.sh slim|restore" >&2; exit 2
    ;;
esac
