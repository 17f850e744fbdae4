"""sessions: when and how often a session was re-processed from its stored raw batches

Revision ID: 0003
Revises: 0002
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("sessions") as b:
        b.add_column(sa.Column("reprocessed_at", sa.DateTime(timezone=True), nullable=True))
        b.add_column(sa.Column("reprocess_count", sa.Integer(), nullable=False, server_default="0"))


def downgrade() -> None:
    with op.batch_alter_table("sessions") as b:
        b.drop_column("reprocess_count")
        b.drop_column("reprocessed_at")
