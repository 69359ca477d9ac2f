#!/usr/bin/env python3
"""Probes of the timing fit on a self-check log (docs/self-check.md, issue 37): the fit as selfcheck/src/timing_fit.rs
does it (global static rotation, Huber IRLS, sigmas clustered by frame), the apparent time error per fifth of the raw
rows, and each pursuit on its own. Usage: .deps/python/bin/python scripts/timing_probe.py LOG.csv [SEQ_LO-SEQ_HI ...]"""
import numpy as np, csv, sys
def load(p):
    r=list(csv.DictReader(open(p)))
    return r
def fit(log, perframe=False, use_u=True, gate=0.25, verbose=True):
    F={int(r['seq']):r for r in load(log)}
    M=load(log.replace('.csv','.matches.csv'))
    rows=[];ys=[];cl=[]
    seqs=sorted({int(m['seq']) for m in M})
    steady=lambda f: all(float(f['accel_%s_deg_s'%e])<=max(gate*float(f['speed_%s_deg_s'%e]),2.0) for e in 'lr')
    used=[s for s in seqs if steady(F[s])]
    idx={s:i for i,s in enumerate(used)}
    for m in M:
        s=int(m['seq']); f=F[s]
        if s not in idx: continue
        j=[float(m['j_x']),float(m['j_y']),float(m['j_z'])]
        sl,sr=float(m['s_l_px_per_ms']),float(m['s_r_px_per_ms'])
        ul,ur=float(m['u_l_px_per_ms']),float(m['u_r_px_per_ms'])
        rl,rr=float(m['row_l']),float(m['row_r'])
        if not use_u: ul=ur=0
        R=float(f['readout_ms'])
        y=float(m['dy_px'])-(ul*(rl-.5)+ur*(rr-.5))*R
        if perframe:
            x=[0.0]*(3*len(used)); k=3*idx[s]; x[k:k+3]=j
        else: x=list(j)
        x+= [sl,sr,(sl-ul)*(rl-.5)+(sr-ur)*(rr-.5)]
        rows.append(x); ys.append(y); cl.append(s)
    A=np.array(rows); y=np.array(ys); cl=np.array(cl)
    w=np.ones(len(y))
    for it in range(30):
        W=np.sqrt(w)
        b=np.linalg.lstsq(A*W[:,None],y*W,rcond=None)[0]
        r=y-A@b; sc=max(1.4826*np.median(abs(r)),1e-4); kh=1.345*sc
        w=np.where(abs(r)<=kh,1,kh/np.maximum(abs(r),1e-12))
    ata=(A*w[:,None]).T@A; inv=np.linalg.pinv(ata)
    meat=np.zeros_like(ata)
    for s in set(cl):
        g=(A[cl==s]*(r[cl==s]*w[cl==s])[:,None]).sum(0); meat+=np.outer(g,g)
    G=len(set(cl)); cov=inv@meat@inv*G/(G-1)
    f0=F[used[0]]; a=0.5-float(f0['readout_anchor'])
    n=A.shape[1]; tl,tr,dR=n-3,n-2,n-1
    def lin(c):
        v=sum(cc*b[i] for i,cc in c); var=sum(ci*cj*cov[i,j] for i,ci in c for j,cj in c); return v,np.sqrt(max(var,0))
    dl=lin([(tl,1),(dR,-a)]); dr=lin([(tr,1),(dR,-a)]); dd=lin([(dR,1)])
    ol=float(f0['offset_l_ms'])-dl[0]; orr=float(f0['offset_r_ms'])-dr[0]; ro=float(f0['readout_ms'])-dd[0]
    if verbose: print(f"{log.split('/')[-1]} pf={perframe} u={use_u} frames={len(used)} off L {ol:.2f}±{dl[1]:.2f} R {orr:.2f}±{dr[1]:.2f} readout {ro:.2f}±{dd[1]:.2f} scale {sc:.3f}")
    return ol,orr,ro


def bins(log, nb=5):
    Fr = {int(r['seq']): r for r in load(log)}
    A, y, cl = [], [], []
    for m in load(log.replace('.csv', '.matches.csv')):
        s = int(m['seq']); f = Fr[s]
        if not all(float(f['accel_%s_deg_s' % e]) <= max(.25 * float(f['speed_%s_deg_s' % e]), 2.0) for e in 'lr'):
            continue
        sl, sr = float(m['s_l_px_per_ms']), float(m['s_r_px_per_ms'])
        ul, ur = float(m['u_l_px_per_ms']), float(m['u_r_px_per_ms'])
        rl, rr = float(m['row_l']), float(m['row_r'])
        x = [float(m['j_x']), float(m['j_y']), float(m['j_z'])] + [0.0] * nb
        x[3 + min(int(rl * nb), nb - 1)] += sl
        x[3 + min(int(rr * nb), nb - 1)] += sr
        A.append(x); y.append(float(m['dy_px']) - (ul * (rl - .5) + ur * (rr - .5)) * float(f['readout_ms'])); cl.append(s)
    A, y, cl = np.array(A), np.array(y), np.array(cl); w = np.ones(len(y))
    for _ in range(30):
        W = np.sqrt(w); b = np.linalg.lstsq(A * W[:, None], y * W, rcond=None)[0]
        r = y - A @ b; kh = 1.345 * 1.4826 * np.median(abs(r)); w = np.where(abs(r) <= kh, 1, kh / np.maximum(abs(r), 1e-12))
    inv = np.linalg.inv((A * w[:, None]).T @ A); meat = 0
    for s in set(cl):
        g = (A[cl == s] * (r[cl == s] * w[cl == s])[:, None]).sum(0); meat = meat + np.outer(g, g)
    cov = inv @ meat @ inv
    print('time error (ms, used - true) per fifth of the raw rows, top first:',
          ' '.join(f"{b[3 + k]:+.2f}+-{np.sqrt(cov[3 + k, 3 + k]):.2f}" for k in range(nb)))


if __name__ == '__main__':
    log = sys.argv[1]
    fit(log)
    bins(log)
    orig = load
    for span in sys.argv[2:]:
        lo, hi = map(int, span.split('-'))
        moving = {int(r['seq']) for r in orig(log) if max(float(r['speed_l_deg_s']), float(r['speed_r_deg_s'])) >= 5.0}
        load = lambda p, lo=lo, hi=hi: [r for r in orig(p) if lo <= int(r['seq']) <= hi or int(r['seq']) not in moving] if p.endswith('matches.csv') else orig(p)
        print(f'frames {lo}-{hi} with those at rest:', end=' '); fit(log)
        load = orig
