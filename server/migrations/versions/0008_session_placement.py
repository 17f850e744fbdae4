"""sessions: placement (where the device is carried: it decides the engine); older sessions ran the foot engine

Revision ID: 0008
Revises: 0007
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


# should SQLite's batch mode rebuild the table, it keeps AUTOINCREMENT (revision 0005)
_KW = {"table_kwargs": {"sqlite_autoincrement": True}}


def upgrade() -> None:
    with op.batch_alter_table("sessions", **_KW) as b:
        b.add_column(sa.Column("placement", sa.String(12), nullable=True))
    # every session before this revision ran the foot engine, whatever its device kind
    op.execute("UPDATE sessions SET placement = 'foot'")


def downgrade() -> None:
    with op.batch_alter_table("sessions", **_KW) as b:
        b.drop_column("placement")
