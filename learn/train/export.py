"""Release weights: a training checkpoint reduced to what inference needs.

``export_model`` keeps the config, the fitted method state and the (EMA) weights, with the
network's parameters in float16 (buffers such as a virtual skeleton's rest mesh stay float32),
and drops the optimizer, scaler and RNG states: the shipped defaults (``pretrained/``) are made
this way. ``learn.train.trainer.load_trained`` reads the result like any checkpoint (weights are
cast back to the model's dtype on load).

    python -m learn.train.export RUN/checkpoints/last.pt pretrained/t_shirt-wrinkles.pt
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import torch

from learn.train.checkpoint import save_checkpoint


def export_model(src: str | os.PathLike, dst: str | os.PathLike, *, half: bool = True,
                 extra: dict | None = None) -> Path:
    """Write the release file of checkpoint ``src`` to ``dst`` (atomically); returns ``dst``.

    Args:
        src: a training checkpoint.
        dst: output file.
        half: store floating parameters, and the method's ``half_state`` entries, as float16.
        extra: more entries for the file (e.g. ``"card"``: training facts for the model card).
    """
    from learn.train.trainer import load_trained

    method, model, ckpt = load_trained(src, device="cpu", use_ema=True)
    params = {n for n, _ in model.named_parameters()}
    sd = {k: (v.half() if half and k in params and v.is_floating_point() else v).clone()
          for k, v in model.state_dict().items()}
    state = {k: (v.half() if half and k in method.half_state and v.is_floating_point() else v)
             for k, v in method.state.items()}
    payload = {"config": ckpt["config"], "step": ckpt["step"], "model": sd,
               "method_state": state, "versions": ckpt.get("versions", {}),
               "exported_from": os.fspath(src), **(extra or {})}
    save_checkpoint(dst, payload)
    return Path(dst)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("src", help="training checkpoint")
    p.add_argument("dst", help="release file to write")
    p.add_argument("--float32", action="store_true", help="keep float32 parameters")
    a = p.parse_args(argv)
    out = export_model(a.src, a.dst, half=not a.float32)
    print(f"wrote {out} ({out.stat().st_size / 2**20:.1f} MiB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    torch.set_num_threads(max(1, torch.get_num_threads()))
    sys.exit(main())
