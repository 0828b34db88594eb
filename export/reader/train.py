"""Train the reader's head: `python -m mosaicthinker.export.reader.train --out DIR --seed 0`.

Generated questions (export/reader/generate.py) go once through the frozen encoder (all-MiniLM-L6-v2 from its
PyPI package, sha256 checked); their word-piece states are cached and the head (export/reader/head.py) is trained
on them, seeded. A second generated set with another seed measures it (kind accuracy, span exact match). Writes
DIR/head.npz + DIR/head.json (docs/query.md: retraining for your own wording or language).
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mosaicthinker.runtime.query.reader_spec import KINDS, MAX_TOKENS, TAGS

from .encoder import extract_encoder, load_encoder
from .generate import Example, dataset
from .head import Head, HeadConfig, load_head, save_head

BATCH = 48
TAG_ID = {t: i for i, t in enumerate(TAGS)}
KIND_ID = {k: i for i, k in enumerate(KINDS)}


def encode(tok: Any, ex: Example) -> tuple[list[int], list[int]]:
    """(word-piece ids with [CLS]/[SEP], one tag id per piece: a word's later pieces continue its span (I-),
    special tokens -100)."""
    enc = tok.encode(ex.words, is_pretokenized=True)
    labels = []
    prev = None
    for wid in enc.word_ids:
        if wid is None:
            labels.append(-100)
            continue
        t = ex.tags[wid]
        if wid == prev and t.startswith("B-"):
            t = "I-" + t[2:]
        labels.append(TAG_ID[t])
        prev = wid
    ids = enc.ids[:MAX_TOKENS]
    return ids, labels[:MAX_TOKENS]


@torch.no_grad()
def features(encoder: Any, rows: list[list[int]], batch: int = 64) -> list[torch.Tensor]:
    """The frozen encoder's last states of each row ([T_i, D] float16), batched by length."""
    out: list[torch.Tensor | None] = [None] * len(rows)
    order = np.argsort([len(r) for r in rows])
    for s in range(0, len(rows), batch):
        idx = order[s:s + batch]
        ids, mask = _pad([rows[i] for i in idx])
        states = encoder(input_ids=ids, attention_mask=mask).last_hidden_state
        for j, i in enumerate(idx):
            out[i] = states[j, :len(rows[i])].to(torch.float16)
        if (s // batch) % 50 == 49:
            print(f"encoder states: {s + len(idx)} of {len(rows)} questions", flush=True)
    return out  # type: ignore[return-value]


def cached_features(encoder: Any, rows: list[list[int]], cache: Path | None, key: str,
                    prov: dict[str, Any]) -> list[torch.Tensor]:
    """`features`, kept in `cache` (features-KEY.pt) for a rerun with the same questions and encoder."""
    path = None if cache is None or prov.get("random_weights") else cache / f"features-{key}.pt"
    if path is not None and path.is_file():
        saved = torch.load(path)
        if saved["rows"] == rows:
            return saved["feats"]
    feats = features(encoder, rows)
    if path is not None:
        torch.save({"rows": rows, "feats": feats}, path.with_suffix(".tmp"))
        path.with_suffix(".tmp").replace(path)
    return feats


def _pad(rows: list[list[int]], value: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    t = max(len(r) for r in rows)
    ids = torch.full((len(rows), t), value, dtype=torch.long)
    mask = torch.zeros((len(rows), t), dtype=torch.long)
    for i, r in enumerate(rows):
        ids[i, :len(r)] = torch.tensor(r)
        mask[i, :len(r)] = 1
    return ids, mask


def _batch(feats: list[torch.Tensor], labels: list[list[int]], kinds: list[int], idx: np.ndarray):
    t = max(feats[i].shape[0] for i in idx)
    x = torch.zeros((len(idx), t, feats[idx[0]].shape[1]))
    mask = torch.zeros((len(idx), t), dtype=torch.long)
    y = torch.full((len(idx), t), -100, dtype=torch.long)
    for j, i in enumerate(idx):
        n = feats[i].shape[0]
        x[j, :n], mask[j, :n], y[j, :n] = feats[i].float(), 1, torch.tensor(labels[i])
    return x, mask, y, torch.tensor([kinds[i] for i in idx])


def batches(lengths: np.ndarray, size: int, rng: np.random.Generator, pool: int = 32) -> list[np.ndarray]:
    """One epoch's batches: shuffled, then questions of similar length batched together within pools of `pool`
    batches (less padding: the head's cost is its padded word pieces), batches in random order."""
    perm = rng.permutation(len(lengths))
    out = []
    for s in range(0, len(perm), size * pool):
        chunk = perm[s:s + size * pool]
        chunk = chunk[np.argsort(lengths[chunk], kind="stable")]
        out += [chunk[i:i + size] for i in range(0, len(chunk), size)]
    return [out[i] for i in rng.permutation(len(out))]


def feature_spread(feats: list[torch.Tensor], rows: int = 2000) -> torch.Tensor:
    """[D] standard deviation of each state dimension over the word pieces of the first `rows` questions."""
    return torch.cat([f.float() for f in feats[:rows]]).std(0)


def evaluate(head: Head, feats, labels, kinds) -> dict[str, float]:
    """Kind accuracy and the share of questions whose every piece tag is right."""
    head.eval()
    ok_kind = ok_tags = 0
    with torch.no_grad():
        for s in range(0, len(feats), 128):
            idx = np.arange(s, min(s + 128, len(feats)))
            x, mask, y, k = _batch(feats, labels, kinds, idx)
            kl, tl = head(x, mask)
            ok_kind += int((kl.argmax(-1) == k).sum())
            pred = tl.argmax(-1)
            ok_tags += int(((pred == y) | (y == -100)).all(-1).sum())
    return {"kind_accuracy": ok_kind / len(feats), "tags_exact": ok_tags / len(feats)}


def train(out: Path, seed: int, n_train: int, n_dev: int, epochs: int, random_encoder: bool = False,
          cache: Path | None = None, noise: float = 0.1, init: Path | None = None,
          lr: float = 1e-3) -> dict[str, Any]:
    t0 = time.time()
    torch.manual_seed(seed)
    cache = cache or Path(tempfile.gettempdir()) / "mosaic-reader-encoder"  # 90 MB: never beside the head
    folder = None if random_encoder else extract_encoder(cache)
    encoder, tok, prov = load_encoder(folder, seed)
    train_ex, dev_ex = dataset(n_train, seed), dataset(n_dev, seed + 1_000_003)
    enc_tr = [encode(tok, e) for e in train_ex]
    enc_dv = [encode(tok, e) for e in dev_ex]
    f_tr = cached_features(encoder, [r for r, _ in enc_tr], cache, f"train-{seed}-{n_train}", prov)
    f_dv = cached_features(encoder, [r for r, _ in enc_dv], cache, f"dev-{seed}-{n_dev}", prov)
    t_feat = time.time() - t0
    print(f"features of {n_train}+{n_dev} questions in {t_feat:.0f} s", flush=True)
    y_tr, k_tr = [lab for _, lab in enc_tr], [KIND_ID[e.kind] for e in train_ex]
    y_dv, k_dv = [lab for _, lab in enc_dv], [KIND_ID[e.kind] for e in dev_ex]
    head = load_head(init)[0] if init is not None else Head(HeadConfig())  # init: go on from a trained head
    opt = torch.optim.AdamW(head.parameters(), lr=lr, weight_decay=0.01)
    rng = np.random.default_rng(seed)
    steps = epochs * ((n_train + BATCH - 1) // BATCH)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.1)
    ce = torch.nn.CrossEntropyLoss(ignore_index=-100)
    # the encoder's states vary per dimension; noise of `noise` x that spread stands in for int8's rounding
    scale = noise * feature_spread(f_tr)
    lengths = np.array([f.shape[0] for f in f_tr])
    for ep in range(epochs):
        head.train()
        tot = 0.0
        for idx in batches(lengths, BATCH, rng):
            x, mask, y, k = _batch(f_tr, y_tr, k_tr, idx)
            if noise > 0:  # a head that reads the same through small changes of the states keeps int8's parity
                x = x + torch.randn_like(x) * scale * mask[..., None]
            kl, tl = head(x, mask)
            loss = ce(kl, k) + ce(tl.reshape(-1, tl.shape[-1]), y.reshape(-1))
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            tot += float(loss.detach()) * len(k)
        print(f"epoch {ep + 1}/{epochs}: loss {tot / n_train:.4f} ({time.time() - t0:.0f} s)", flush=True)
    print(f"dev {evaluate(head, f_dv, y_dv, k_dv)}", flush=True)
    info = {"seed": seed, "n_train": n_train, "n_dev": n_dev, "epochs": epochs, "feature_noise": noise, "lr": lr,
            "init": str(init) if init is not None else None,
            "encoder": prov,
            "dev": evaluate(head, f_dv, y_dv, k_dv), "train_s": round(time.time() - t0, 1),
            "features_s": round(t_feat, 1), "torch_threads": torch.get_num_threads()}
    save_head(head, out, info)
    print(f"wrote {out}/head.npz, head.json ({info['train_s']} s)", flush=True)
    return info


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, type=Path, help="folder for head.npz + head.json")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--train", type=int, default=20000, help="generated training questions")
    p.add_argument("--dev", type=int, default=1000, help="generated questions (another seed) measuring it")
    p.add_argument("--epochs", type=int, default=5)  # the committed head's
    p.add_argument("--noise", type=float, default=0.1, help="training noise on the states, x their spread")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--lr", type=float, default=1e-3, help="the one-cycle schedule's peak learning rate")
    p.add_argument("--init", type=Path, help="go on training this head folder (head.npz + head.json)")
    p.add_argument("--random-encoder", action="store_true", help="random weights of the real configuration (test)")
    p.add_argument("--cache", type=Path, help="folder for the extracted encoder and the cached encoder states "
                                              "(default: the temp folder's mosaic-reader-encoder)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    train(a.out, a.seed, a.train, a.dev, a.epochs, a.random_encoder, a.cache, a.noise, a.init, a.lr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
